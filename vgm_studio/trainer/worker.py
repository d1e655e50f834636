"""The trainer process: watches a workspace's labels and trains, registers and promotes versions.

One cycle: read the human labels (majority per edge), deal new ones to the sticky held-out
split, train from the active version (or from scratch), judge the result on the held-out edges
against the active model's stored predictions for the same edges, predict every edge, then
register the version — promoted, with its predictions, only when it is not worse.

It runs beside the app on a shared CPU, so it uses one torch thread and a lower priority.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vgm_studio.labels.opening import open_store
from vgm_studio.labels.records import NewVersion
from vgm_studio.labels.store import LabelStore
from vgm_studio.model.checkpoint import Checkpoint, load_checkpoint
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.model.validator import Validator
from vgm_studio.trainer import registry
from vgm_studio.trainer.dataset import BaseSet, SampleCache, TrainingSet, training_set
from vgm_studio.trainer.fit import FitConfig, FitResult, fit, payload, write_checkpoint
from vgm_studio.trainer.lock import take_lock
from vgm_studio.trainer.promotion import Contest, PromotionRule, Scored, verdict


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
        promotion: What a version must show before it replaces the model in use.
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
    promotion: PromotionRule = field(default_factory=PromotionRule)


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
        url: str | None = None,
    ) -> None:
        self.config = config
        self.log = log
        self.parent_pid = parent_pid
        self.store = open_store(workspace, url, create=False, durable=False)
        # A team store's lock lives in the database, so trainers on other hosts see it too.
        self._lock = take_lock(self.store.workspace) if url is None else _team_lock_of(self.store)
        context = config.fit.context
        self.cache = SampleCache(self.store, context)
        self.base = BaseSet.read(config.base, config.held_out, config.fit.seed, context)
        self._guard_cache: tuple[str, Scored | None] | None = None
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
        return self.store.trainer.progress(self.seen)

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
        version, judged = self._register(job, data, result, newest, start)
        acc = result.metrics.get("accuracy", float("nan"))
        kept = judged.get("against") or "no model"
        what = "promoted" if judged["promote"] else f"not promoted, {kept} stays in use"
        line = f"v{version}: held-out accuracy {acc:.3f} on {len(data.held_out)} edges; {what}"
        if not judged["promote"]:
            line += f": {judged['reason']}"
        self.log(line)
        registry.report(self.store, "idle", message=line)
        return version

    def _register(
        self, job: Job, data: TrainingSet, result: FitResult, newest: int, start: float
    ) -> tuple[int, dict[str, Any]]:
        """Judges a trained version and registers it (promoted or not) with the requests it
        serves and the watermark, in one transaction; returns N and the verdict."""
        judged = self._compare(data, result)
        predictions = self._predict_all(result) if judged["promote"] else None
        counts = data.counts()
        metrics = {
            **result.metrics,
            "threshold": result.threshold,
            "compared": judged,
            "counts": counts,
            "base_edges": len(data.edge_ids) - data.workspace_labels,
            "warm_start": result.warm_start,
            "epochs_run": len(result.history),
        }
        training = {
            "counts": counts,
            "seconds": time.perf_counter() - start,
            "workspace": str(self.store.workspace),
        }
        tmp = write_checkpoint(
            self.store.workspace / registry.MODELS_DIR, payload(result, self.config.fit, training)
        )
        new = NewVersion(
            checkpoint=tmp,
            metrics=metrics,
            labels_seen=data.workspace_labels,
            seconds=time.perf_counter() - start,
            promote=bool(judged["promote"]),
            predictions=predictions,
            threshold=result.threshold,
            state={"events_seen": str(newest)},
            requests_served=job.request,
        )
        version = registry.register_model(self.store, new)
        self.seen = newest
        return version, judged

    def _skip(self, job: Job, newest: int, why: str) -> None:
        self.store.trainer.finish(job.request)
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
        """The promotion verdict (``promotion.py``): the version against the model in use.

        The model in use is judged by its stored predictions at its own cut; held-out edges
        were never trained on by any version, and the bundled model never saw this log.
        """
        held = data.labels[data.held_out]
        contest = Contest(new=Scored(held, result.held_out_p, result.threshold))
        active = self.store.predictions()
        if active.model is not None:
            name = registry.version_of(active.model)
            rows = [k for k, i in enumerate(data.held_out) if data.edge_ids[i] in active.p]
            theirs = np.array([active.p[data.edge_ids[data.held_out[k]]] for k in rows])
            contest = replace(
                contest,
                active_name=f"v{name}" if name is not None else active.model,
                active=Scored(held[rows], theirs, active.threshold) if rows else None,
            )
        if len(self.base.guard_labels):
            guard_p = self._validator(result).predict_samples(self.base.guard_samples, 128)
            contest = replace(
                contest,
                guard_new=Scored(self.base.guard_labels, guard_p, result.threshold),
                guard_active=self._guard_of(active.model),
            )
        return verdict(contest, self.config.promotion)

    def _guard_of(self, model: str | None) -> Scored | None:
        """The model in use on the guard set (None: no model in use, or its file is unknown)."""
        if self._guard_cache is not None and self._guard_cache[0] == model:
            return self._guard_cache[1]
        path = _checkpoint_of(self.store.workspace, model)
        scored = None
        if path is not None and path.is_file():
            validator = Validator.load(path, device="cpu")
            # A model in use that reads its pairs otherwise than the trainer's versions is
            # judged on the guard edges drawn its way.
            p = (
                validator.predict_samples(self.base.guard_samples, 128)
                if validator.context == self.config.fit.context
                else validator.predict(self.base.guard_edges, batch_size=128)
            )
            scored = Scored(self.base.guard_labels, p, validator.threshold)
        self._guard_cache = (model or "", scored)
        return scored

    def _validator(self, result: FitResult) -> Validator:
        return Validator(payload(result, self.config.fit, {}), device="cpu")

    def _predict_all(self, result: FitResult) -> dict[str, float]:
        validator = self._validator(result)
        ids = list(self.cache.edges)
        p = validator.predict_samples([self.cache.samples[e] for e in ids], batch_size=128)
        return dict(zip(ids, (float(v) for v in p), strict=True))


def _checkpoint_of(workspace: Path, model: str | None) -> Path | None:
    """The file of the model whose predictions are in use: a version's, or the bundled one."""
    version = registry.version_of(model)
    if version is not None:
        return registry.model_path(workspace, version)
    if model is not None and model.startswith(f"{BUNDLED_MODEL.name}:"):
        return BUNDLED_MODEL
    return None


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


def _team_lock_of(store: LabelStore) -> LabelStore:
    """The team store's trainer lock: a session advisory lock the server frees with the
    connection, so a killed trainer on any host leaves none behind."""
    store.trainer_lock()  # type: ignore[attr-defined]
    return store  # the lock is held as long as the store's connection
