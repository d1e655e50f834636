"""Shared bits of the benchmark scripts: the machine line, timing, datasets, tables."""

from __future__ import annotations

import multiprocessing
import os
import platform
import statistics
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from datetime import date
from pathlib import Path
from typing import Any, TypeVar

Job = TypeVar("Job")
Result = TypeVar("Result")

# On a CPU the RGB baseline (2 ms a pair) trains fewer, smaller epochs than TrainConfig's
# defaults: (epochs, draws per epoch). Its tables' last columns say so.
RGB_CPU_RECIPE = (6, 3000)

REPO = Path(__file__).resolve().parents[1]


def datasets_dir() -> Path:
    env = os.environ.get("VGM_STUDIO_DATASETS")
    path = Path(env) if env else REPO.parent / "shared" / "datasets"
    if not path.is_dir():
        raise SystemExit(f"real datasets not found at {path} (set VGM_STUDIO_DATASETS)")
    return path


def pin_to_cores(count: int) -> None:
    """Restricts this process to ``count`` cores, as the targets are stated per core."""
    cores = sorted(os.sched_getaffinity(0))[:count]
    os.sched_setaffinity(0, cores)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(count)


def watch_parent() -> None:
    """Ends this process once the process that spawned it is gone: a killed run would
    otherwise leave its spawned workers training on, each on a core, with no one to take
    their results."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def spawned(
    job: Callable[[Job], Result],
    jobs: Iterable[Job],
    processes: int,
    start: Callable[..., None],
    start_args: tuple[Any, ...],
) -> Iterator[Result]:
    """``job``'s results as they end, run by ``processes`` spawned workers, each begun with
    ``start(*start_args)``. Spawned, not forked: a pool forked after the parent had loaded
    the edges hung before its first job on a 16-core GPU machine (cause not traced)."""
    with multiprocessing.get_context("spawn").Pool(processes, start, start_args) as pool:
        yield from pool.imap_unordered(job, jobs)
        pool.close()  # every job is done: let the workers end rather than be terminated
        pool.join()


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {date.today()}"


def median_time(fn: Callable[[], object], repeat: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
    return statistics.median(samples)


def table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table, ready to paste into BENCHMARKS.md."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=True)]
    line = "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = [
        "| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)) + " |"
        for r in rows
    ]
    return "\n".join([line, sep, *body])
