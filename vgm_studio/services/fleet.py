"""``vgm-studio fleet``: every log of a manifest through candidates, validation and SLAM, on Ray.

Each Ray worker is a long-lived actor that loads the model once and then takes log after
log (``fleet_log.process_log``, the single-log commands' services). Without an address a
local Ray is started on this machine, so a laptop and a cluster run the same code. A log
that fails becomes a failed row and the others go on; a worker process that dies is
restarted by Ray and the log run again on it, up to ``max_attempts`` times. A log whose
folder holds a finished row with the same key (the log's sha256, its references and the
settings) is skipped, so a fleet run stopped half-way resumes where it was.
"""

from __future__ import annotations

import json
import os
import time
import uuid
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vgm_studio.atomic import write_json_atomically
from vgm_studio.datasets.manifest import ManifestEntry, read_manifest
from vgm_studio.errors import InputError
from vgm_studio.progress import counter
from vgm_studio.services import Say, quiet
from vgm_studio.services.fleet_log import (
    RUNNING_FILE,
    FleetSettings,
    base_row,
    finished_row,
    log_folder,
    log_key,
    process_log,
)
from vgm_studio.services.fleet_table import (
    GRID_FILE,
    TABLE_FILE,
    summary_lines,
    write_grid,
    write_table,
)


@dataclass(frozen=True)
class RayOptions:
    """Where the fleet runs.

    Attributes:
        address: An existing Ray cluster (``ray://HOST:10001`` or ``HOST:6379``); None starts a
            local Ray on this machine.
        num_cpus: CPUs of the local Ray (None: all of this machine's).
        workers: Workers (one CPU each; None: one per CPU of the cluster).
        temp_dir: The local Ray's session folder (None: Ray's default); keep it short, Ray
            puts Unix sockets in it.
        max_attempts: Times a log is run when its worker process dies under it.
    """

    address: str | None = None
    num_cpus: int | None = None
    workers: int | None = None
    temp_dir: Path | None = None
    max_attempts: int = 3


@dataclass(frozen=True)
class FleetRun:
    """A fleet run: the rows in manifest order and where the outputs went."""

    rows: list[dict[str, Any]]
    table: Path
    grid: Path
    workers: int
    seconds: float

    def lines(self) -> list[str]:
        return [
            *summary_lines(self.rows),
            f"wrote {self.table} and {self.grid} ({self.workers} worker(s), {self.seconds:.0f} s)",
        ]


class LogWorker:
    """A fleet worker: holds the model, runs one log per call.

    Made a Ray actor by ``_actor_class``; Ray restarts it (running ``__init__`` again) when its
    process dies.
    """

    def __init__(self, model: str, threads: int = 1) -> None:
        import torch

        from vgm_studio.model.cache import shared_validator

        # A worker holds one CPU: more torch threads would fight the other workers for it.
        torch.set_num_threads(threads)
        shared_validator(Path(model))

    def run(self, job: LogJob) -> dict[str, Any]:
        """The log's row; an error in this log becomes a failed row, never an exception.

        A log whose worker died under it is run again by Ray on the restarted worker; the
        ``running.json`` it left behind counts the attempts, and past ``max_attempts`` the
        log is given up as a failed row instead of being run once more.
        """
        from vgm_studio.model.cache import load_count

        entry = job.entry
        folder = log_folder(job.out, entry)
        folder.mkdir(parents=True, exist_ok=True)
        running = folder / RUNNING_FILE
        attempt = _previous_attempts(running, job.run_id) + 1
        write_json_atomically(
            running, {"pid": os.getpid(), "attempt": attempt, "run_id": job.run_id}
        )
        row = base_row(entry, job.log_sha, job.key)
        start = time.perf_counter()
        if attempt > job.max_attempts:
            row["error"] = f"its worker died {attempt - 1} times while running it; given up"
        else:
            try:
                row = process_log(entry, job.settings, job.out, job.log_sha, job.key)
            except InputError as exc:
                row["error"] = str(exc)
            except Exception as exc:  # a bug in one log must not stop the fleet's other logs
                row["error"] = f"{type(exc).__name__}: {exc}"
        row.setdefault("seconds", time.perf_counter() - start)  # a failed log's time too
        row.update(attempts=attempt, worker_pid=os.getpid(), model_loads=load_count())
        write_json_atomically(folder / "row.json", row)
        running.unlink(missing_ok=True)
        return row


@dataclass(frozen=True)
class LogJob:
    """One log handed to a worker, with what it needs to run it and to count attempts."""

    entry: ManifestEntry
    settings: FleetSettings
    out: Path
    log_sha: str
    key: str
    run_id: str
    max_attempts: int


def _previous_attempts(running: Path, run_id: str) -> int:
    """Attempts of this fleet run on the log before now (a running file left by a dead worker)."""
    try:
        doc = json.loads(running.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return 0
    if not isinstance(doc, dict) or doc.get("run_id") != run_id:
        return 0  # left by an earlier fleet run that was stopped: not this run's attempt
    return int(doc.get("attempt", 0))


def run_fleet(
    manifest: Path,
    out: Path,
    settings: FleetSettings,
    ray_options: RayOptions | None = None,
    *,
    progress: bool = True,
    say: Say = quiet,
) -> FleetRun:
    """Runs every log of the manifest not done before; writes the table and the map grid.

    Raises:
        InputError: The manifest is bad, a listed file cannot be read, Ray cannot start or
            be reached, or the outputs cannot be written.
    """
    start = time.perf_counter()
    entries = read_manifest(manifest)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(out, f"cannot make the output folder ({exc.strerror or exc})") from None
    keys = {e.name: _key(e, settings) for e in entries}
    rows: dict[str, dict[str, Any]] = {}
    todo = []
    for e in entries:
        row = finished_row(out, e, keys[e.name][1])
        if row is None:
            todo.append(e)
        else:
            rows[e.name] = {**row, "skipped": True}
    say(f"{len(entries)} logs: {len(entries) - len(todo)} done before, {len(todo)} to run")
    workers = 0
    if todo:
        with ray_session(ray_options or RayOptions()) as (ray, cpus):
            options = ray_options or RayOptions()
            workers = max(1, min(options.workers or cpus, len(todo)))
            say(f"Ray: {cpus} CPU(s), {workers} worker(s)")
            rows.update(_dispatch(ray, todo, keys, settings, out, workers, options, progress))
    ordered = [{**rows[e.name], "skipped": rows[e.name].get("skipped", False)} for e in entries]
    table = write_table(out / TABLE_FILE, ordered)
    grid = write_grid(out / GRID_FILE, ordered)
    return FleetRun(ordered, table, grid, workers, time.perf_counter() - start)


def _key(entry: ManifestEntry, settings: FleetSettings) -> tuple[str, str]:
    try:
        return log_key(entry, settings)
    except OSError as exc:
        raise InputError(entry.log, f"cannot read ({exc.strerror or exc})") from None


@contextmanager
def ray_session(options: RayOptions) -> Iterator[tuple[Any, int]]:
    """Ray connected (or started locally), and the cluster's CPUs; shut down if started here.

    A Ray already initialised in this process (a notebook, a test) is used as it is.
    """
    try:
        import ray
    except ImportError:
        raise InputError(
            None, "fleet needs Ray: pip install 'vgm-studio[fleet]' (ray and pyarrow)"
        ) from None
    started = not ray.is_initialized()
    if started:
        # Workers' output (SLAM's progress bars) stays in Ray's logs: the driver shows one bar.
        kwargs: dict[str, Any] = {"log_to_driver": False}
        try:
            if options.address is not None:
                ray.init(address=options.address, **kwargs)
            else:
                if options.temp_dir is not None:
                    kwargs["_temp_dir"] = str(options.temp_dir)
                cpus = options.num_cpus or os.cpu_count() or 1
                ray.init(num_cpus=cpus, include_dashboard=False, **kwargs)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            where = options.address or "a local Ray"
            raise InputError(None, f"cannot start or reach {where}: {exc}") from None
    try:
        yield ray, int(ray.cluster_resources().get("CPU", 1))  # type: ignore[no-untyped-call]
    finally:
        if started:
            ray.shutdown()


def _actor_class(ray: Any) -> Any:
    # A worker whose process dies comes back (its model loaded again), and the call it was
    # running is retried on it; the worker counts the attempts and gives the log up.
    return ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=-1)(LogWorker)


def _dispatch(
    ray: Any,
    todo: list[ManifestEntry],
    keys: dict[str, tuple[str, str]],
    settings: FleetSettings,
    out: Path,
    workers: int,
    options: RayOptions,
    progress: bool,
) -> dict[str, dict[str, Any]]:
    """Hands logs to idle workers until every log has a row."""
    actor = _actor_class(ray)
    pool = [actor.remote(str(settings.model)) for _ in range(workers)]
    run_id = uuid.uuid4().hex
    queue = deque(todo)
    idle = list(range(workers))
    pending: dict[Any, tuple[ManifestEntry, int]] = {}
    rows: dict[str, dict[str, Any]] = {}
    bar = counter(len(todo), "fleet", "log", enabled=progress)
    while queue or pending:
        while queue and idle:
            entry, w = queue.popleft(), idle.pop()
            log_sha, key = keys[entry.name]
            job = LogJob(entry, settings, out, log_sha, key, run_id, options.max_attempts)
            pending[pool[w].run.remote(job)] = (entry, w)
        (ref,), _ = ray.wait(list(pending), num_returns=1)
        entry, w = pending.pop(ref)
        idle.append(w)
        try:
            row = ray.get(ref)
        except ray.exceptions.RayError as exc:  # Ray gave the worker up, not the log's error
            first = (str(exc).strip() or type(exc).__name__).splitlines()[0]
            row = {**base_row(entry, *keys[entry.name]), "error": f"worker lost: {first}"}
        rows[entry.name] = row
        bar.set_postfix(last=f"{entry.name} {row['status']}")
        bar.update(1)
    bar.close()
    for handle in pool:
        ray.kill(handle)
    return rows
