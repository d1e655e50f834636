"""Serving a workspace: the studio, the model's predictions and the trainer beside it.

``serve`` is what ``vgm-studio label`` and ``demo`` run once the workspace is filled: it starts
the studio, makes the model's predictions in the background (the annotator can start at once),
starts the background trainer and the watcher that brings its versions to the tabs, and
serves until Ctrl-C.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from vgm_studio.errors import InputError
from vgm_studio.labels.opening import store_url
from vgm_studio.labels.store import LabelStore
from vgm_studio.studio.app import Studio, StudioConfig
from vgm_studio.studio.gate import is_loopback
from vgm_studio.studio.panel import trainer_text
from vgm_studio.studio.scoring import Scorer
from vgm_studio.trainer import PromotionWatcher, TrainerSupervisor, request_training
from vgm_studio.trainer.lock import held_elsewhere

EXPOSED = (
    "anyone who can reach {host}:{port} and has the address above (its token) can read and "
    "change these labels, over plain HTTP. Listen on 127.0.0.1 (the default) unless the "
    "network is trusted."
)
KEYS = (
    "  keys: S success · F failure · D skip · Z undo · Q previous · E next · G guess"
    " · V points/VGM · R reset view"
)


@dataclass
class TrainerOptions:
    """The background trainer beside the studio (see ``vgm_studio.trainer``)."""

    retrain_every: int = 25
    base: list[Path] = field(default_factory=list)
    min_held_out: int = 20

    @classmethod
    def checked(
        cls, retrain_every: int, base: list[Path] | None, min_held_out: int = 20
    ) -> TrainerOptions:
        """Checks the base files now: one missing would crash the trainer over and over.

        Raises:
            InputError: A base file is missing.
        """
        for path in base or []:
            if not path.is_file():
                raise InputError(path, "no such --base edges file")
        return cls(retrain_every, [p.resolve() for p in base or []], min_held_out)


def _say(line: str) -> None:
    print(line, flush=True)


def _warn(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _start_trainer(studio: Studio, options: TrainerOptions) -> Callable[[], None]:
    """Starts the trainer process and the watcher that brings its versions to the app.

    When another studio's trainer (or one started alone) already runs on the store, the
    supervisor starts none and this studio shows that trainer's versions; it starts its own
    once that one ends.

    Returns:
        A function that stops both.
    """
    url = store_url(studio.store)
    if held_elsewhere(studio.store.workspace, url):
        _say(
            "  trainer: another one runs on this workspace already; this studio uses it "
            "(and starts its own if that one ends)"
        )
    supervisor = TrainerSupervisor(
        studio.store.workspace,
        options.retrain_every,
        options.base,
        extra_args=["--min-held-out", str(options.min_held_out)],
        url=url,
    )
    watcher = PromotionWatcher(
        studio.store,
        on_promote=lambda _name: studio.refresh_predictions(),
        on_status=lambda status: studio.show_trainer(trainer_text(status)),
    )
    supervisor.start()
    watcher.start()

    def stop() -> None:
        watcher.stop()
        supervisor.stop()

    return stop


def _score(studio: Studio, model: Path, precision: float | None) -> None:
    """Scores the edges, those on screen first, and shows them as they come (``Scorer``)."""
    scorer = Scorer(studio.store, model, studio.upcoming, studio.show_scores, precision=precision)
    scorer.run()


def _score_then_refresh(studio: Studio, model: Path, precision: float | None) -> None:
    try:
        _score(studio, model, precision)
    except Exception as exc:  # a failed model must not take the labeling down
        _warn(f"{model}: no predictions ({exc})")
        studio.show_scores(studio.store.predictions(), None)
        return
    studio.refresh_predictions()


def serve(
    store: LabelStore,
    config: StudioConfig,
    *,
    model: Path | None = None,
    precision: float | None = None,
    trainer: TrainerOptions | None = None,
    started: float | None = None,
) -> None:
    """Starts the studio (and the trainer beside it), says where, and serves until Ctrl-C.

    The model's predictions are made in the background: the annotator can start at once; the
    edges on screen are scored first, and the panel says how far scoring got. With
    ``precision`` the model's calls are cut where its validation precision reaches it
    (``scoring.Scorer``). ``started``
    (on ``time.perf_counter``'s clock) is when the wait began, for "ready N s after start".
    """

    def train_now() -> None:
        request_training(store)

    studio = Studio(store, config, train_now=train_now if trainer is not None else None)
    studio.start()
    stop_trainer = _start_trainer(studio, trainer) if trainer is not None else None
    if model is not None:
        threading.Thread(
            target=_score_then_refresh,
            args=(studio, model, precision),
            daemon=True,
            name="predict",
        ).start()
    ready = None if started is None else time.perf_counter() - started
    when = f" (ready {ready:.1f} s after start)" if ready is not None else ""
    _say(f"VGM Studio: {store.count_edges()} edges at {studio.url}{when}")
    link = studio.first_link()
    if link is not None:
        # ?edge= opens any edge by its id; &queue= names the queue it is shown in.
        _say(f"  link to an edge: {link}")
    _say(KEYS)
    if not is_loopback(config.host):
        _warn("  warning: " + EXPOSED.format(host=config.host, port=config.port))
    _say("  Ctrl-C stops; every label is already saved.")
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        _say("stopped; labels are in " + str(store.path))
    finally:
        if stop_trainer is not None:
            stop_trainer()
        studio.stop()
        store.close()


def added_text(store: LabelStore, source: Path, before: int, added: int) -> str:
    """What a source added to a workspace that had edges: counts by kind, or none."""
    if not added:
        return f"{source}: already in {store.workspace}; no edges added ({before} there)"
    kinds = Counter(edge.kind for edge in store.edges()[before:])
    which = ", ".join(f"{n} {kind}" for kind, n in sorted(kinds.items()))
    return f"{source}: added {added} edges ({which}) to the {before} in {store.workspace}"
