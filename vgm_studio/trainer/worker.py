"""The trainer process: watches a workspace's labels and trains, registers and promotes versions.

One cycle: read the human labels (majority per edge), deal new ones to the sticky held-out
split, train from the active version (or from scratch), judge the result on the held-out edges
against the active model's stored predictions for the same edges, predict every edge, then
register the version — promoted, with its predictions, only when it is not worse.

It runs beside the app on a shared CPU, so it uses one torch thread and a lower priority.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vgm_studio.errors import InputError
from vgm_studio.labels.store import LabelStore
from vgm_studio.model.checkpoint import Checkpoint, load_checkpoint
from vgm_studio.model.metrics import binary_metrics
from vgm_studio.model.validator import Validator
from vgm_studio.trainer import registry
from vgm_studio.trainer.dataset import BaseSet, SampleCache, TrainingSet, training_set
from vgm_studio.trainer.fit import FitConfig, FitResult, fit, payload, write_checkpoint


@dataclass(frozen=True)
class TrainerConfig:
    """What the trainer does and when.

    Attributes:
        retrain_every: Train after this many new labels.
        base: Labelled edge files trained on besides the workspace's labels.
        from_scratch: Every version starts from fresh weights (else from the active one).
        poll_seconds: How often the store is looked at.
        held_out: Share of each (log, label) group of labelled edges held out.
        min_per_class: Labels of each class needed in training before a first version.
        threads: torch CPU threads; one leaves the other core to the app.
        nice: Added to the process's niceness; when not 0 the process also runs under
            SCHED_IDLE (Linux), so the app and the browser always win a contested core.
        fit: The training recipe.
    """

    retrain_every: int = 25
    base: tuple[Path, ...] = ()
    from_scratch: bool = False
    poll_seconds: float = 1.0
    held_out: float = 0.2
    min_per_class: int = 2
    threads: int = 1
    nice: int = 10
    fit: FitConfig = field(default_factory=FitConfig)


class Stop(Exception):
    """Raised inside a training run to end it (the parent process is gone)."""


@dataclass(frozen=True)
class Job:
    """One training to do: from scratch or not, and the last request it serves (0: none)."""

    from_scratch: bool
    request: int


class Worker:
    """The trainer of one workspace. Only one runs per workspace (a lock file says so).

    Example:
        >>> Worker(Path("ws"), TrainerConfig(retrain_every=25)).run()
    """

    def __init__(
        self,
        workspace: Path,
        config: TrainerConfig,
        parent_pid: int | None = None,
        log: Callable[[str], None] = print,
    ) -> None:
        self.config = config
        self.log = log
        self.parent_pid = parent_pid
        self.store = LabelStore(workspace, create=False, durable=False)
        self._lock = _take_lock(self.store.workspace)
        self.cache = SampleCache(self.store)
        self.base = BaseSet.read(config.base)
        registry.ensure_tables(self.store)
        for path in registry.remove_orphans(self.store):
            log(f"removed {path.name}: a checkpoint never registered (a trainer was stopped)")
        # New labels are counted from what the last version read; a cycle killed part way is
        # therefore done again by the next trainer.
        self.seen = int(registry.read_state(self.store).get("events_seen", "0"))

    def run(self, cycles: int | None = None) -> None:
        """Watches the store and trains when due; stops after ``cycles`` trainings (None: never)."""
        _be_polite(self.config)
        registry.report(self.store, "idle", message="watching the labels", pid=os.getpid())
        done = 0
        state: registry.State = "stopped"
        message = "trainer stopped"
        try:
            while cycles is None or done < cycles:
                self._check_parent()
                job = self.due()
                if job is None:
                    time.sleep(self.config.poll_seconds)
                    continue
                self.cycle(job)
                done += 1
        except Exception as exc:  # say why in the app before the process goes
            state, message = "crashed", f"{type(exc).__name__}: {exc}"
            raise
        finally:
            registry.report(self.store, state, message=message)

    def _check_parent(self) -> None:
        """A trainer whose app died stops instead of training for nobody."""
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            raise Stop("the app that started the trainer is gone")

    def _new_labels(self) -> tuple[int, int]:
        """(labels made since the last version's data was read, the newest event id)."""
        with self.store.snapshot() as db:
            newest = db.execute("SELECT COALESCE(MAX(id), 0) FROM events").fetchone()[0]
            count = registry.labels_since(db, self.seen)
        return count, int(newest)

    def due(self) -> Job | None:
        """The training to do now, if any: a request, or enough new labels."""
        requests = registry.pending_requests(self.store)
        if requests:
            return Job(self.config.from_scratch or any(s for _, s in requests), requests[-1][0])
        count, _ = self._new_labels()
        if count >= self.config.retrain_every:
            return Job(self.config.from_scratch, 0)
        return None

    def cycle(self, job: Job) -> int | None:
        """Trains, judges and registers one version; returns N, or None when it could not train."""
        start = time.perf_counter()
        _, newest = self._new_labels()
        data = training_set(
            self.store, self.cache, self.base, self.config.held_out, self.config.fit.seed
        )
        counts = data.counts()
        need = self.config.min_per_class
        if min(counts["train"].values()) < need:
            self._skip(job, newest, f"waiting for labels: training needs {need} of each class")
            return None
        init = None if job.from_scratch else self._warm_start()
        self.log(
            f"training on {counts['train']} (held out {counts['held_out']}), "
            f"{'from scratch' if init is None else 'from the active version'}"
        )
        result = fit(
            data.samples,
            data.labels,
            data.train,
            data.held_out,
            self.config.fit,
            init,
            on_epoch=self._on_epoch,
        )
        verdict = self._compare(data, result)
        promote = verdict["promote"]
        predictions = self._predict_all(result) if promote else None
        train_seconds = time.perf_counter() - start
        metrics = {
            **result.metrics,
            "threshold": result.threshold,
            "compared": verdict,
            "counts": counts,
            "base_edges": len(data.edge_ids) - data.workspace_labels,
            "warm_start": result.warm_start,
            "epochs_run": len(result.history),
        }
        content = payload(
            result,
            self.config.fit,
            {"counts": counts, "seconds": train_seconds, "workspace": str(self.store.workspace)},
        )
        tmp = write_checkpoint(self.store.workspace / registry.MODELS_DIR, content)
        with self.store.transaction() as db:  # the version, its requests and watermark at once
            version = registry.register_model(
                self.store,
                tmp,
                metrics,
                data.workspace_labels,
                time.perf_counter() - start,
                promote,
                predictions,
                result.threshold,
                state={"events_seen": str(newest)},
            )
            registry.finish_requests(db, job.request)
        self.seen = newest
        acc = result.metrics.get("accuracy", float("nan"))
        what = "promoted" if promote else f"kept v{verdict.get('against')} ({verdict['reason']})"
        line = f"v{version}: held-out accuracy {acc:.3f} on {len(data.held_out)} edges; {what}"
        self.log(line)
        registry.report(self.store, "idle", message=line)
        return version

    def _skip(self, job: Job, newest: int, why: str) -> None:
        with self.store.transaction() as db:
            registry.finish_requests(db, job.request)
        # Not written to the store: the labels still count towards the next version.
        self.seen = newest
        registry.report(self.store, "idle", message=why)
        self.log(why)

    def _on_epoch(self, epoch: int, epochs: int) -> None:
        self._check_parent()
        registry.report(self.store, "training", epoch=epoch, epochs=epochs, message="training")

    def _warm_start(self) -> Checkpoint | None:
        """The active version's checkpoint, else the newest version's, else None."""
        models = registry.list_models(self.store)
        chosen = next((m for m in models if m.active), models[-1] if models else None)
        if chosen is None:
            return None
        return load_checkpoint(chosen.path)

    def _compare(self, data: TrainingSet, result: FitResult) -> dict[str, Any]:
        """Promote unless the active model is more accurate on the same held-out edges.

        The active model is judged by its stored predictions at its own cut; held-out edges
        were never trained on by any version, and the bundled model never saw this log.
        """
        active = self.store.predictions()
        if active.model is None:
            return {"promote": True, "reason": "no model in use"}
        rows = [k for k, i in enumerate(data.held_out) if data.edge_ids[i] in active.p]
        if not rows:
            return {"promote": True, "reason": "the model in use has no held-out predictions"}
        labels = data.labels[data.held_out][rows]
        theirs = np.array([active.p[data.edge_ids[data.held_out[k]]] for k in rows])
        old = binary_metrics(labels, theirs, active.threshold)["accuracy"]
        new = binary_metrics(labels, result.held_out_p[rows], result.threshold)["accuracy"]
        better = new >= old
        return {
            "promote": better,
            "reason": "not worse" if better else "worse on the held-out edges",
            "against": registry.version_of(active.model) or active.model,
            "edges": len(rows),
            "accuracy": new,
            "active_accuracy": old,
        }

    def _predict_all(self, result: FitResult) -> dict[str, float]:
        content = payload(result, self.config.fit, {})
        validator = Validator(content, device="cpu")
        ids = list(self.cache.edges)
        p = validator.predict_samples([self.cache.samples[e] for e in ids], batch_size=128)
        return dict(zip(ids, (float(v) for v in p), strict=True))


def _be_polite(config: TrainerConfig) -> None:
    """One torch thread and a lower priority: the app keeps a core to itself."""
    torch.set_num_threads(config.threads)
    # Refused once work has run (tests train in-process): the intra-op count is what counts.
    with contextlib.suppress(RuntimeError):
        torch.set_num_interop_threads(1)
    if config.nice:
        os.nice(config.nice)
        # Niceness alone still lets it take a share of a core the studio and the browser want
        # (p95 label latency 114 → 184 ms on two cores); SCHED_IDLE runs it only on idle time.
        with contextlib.suppress(AttributeError, OSError):  # not Linux
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


def _take_lock(workspace: Path) -> Any:
    """An exclusive lock on the workspace's trainer; the kernel frees it when the process dies."""
    folder = workspace / registry.MODELS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    handle = (folder / ".trainer.lock").open("a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        raise InputError(workspace, "another trainer is running on this workspace") from None
    return handle
