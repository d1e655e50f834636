"""The app's ear on the trainer: polls the store and calls back on a promotion or a new status.

The trainer is another process; the only thing the two share is the workspace's store, so the
app learns of a new active version by reading it (a few small queries a second).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable

from vgm_studio.labels.store import LabelStore
from vgm_studio.trainer.registry import TrainerStatus, trainer_status


class PromotionWatcher:
    """Calls ``on_promote`` when the store's active model changes, ``on_status`` on each poll.

    Callbacks run in the watcher's thread; an exception in one is swallowed (the app's
    labeling must not stop because a redraw failed).

    Args:
        store: The app's store.
        on_promote: Called with the new active model's name (``v7``, say) after a change.
        on_status: Called with every status read (to show it in the panel).
        interval: Seconds between polls.

    Example:
        >>> watcher = PromotionWatcher(store, lambda _name: studio.refresh_predictions())
        >>> watcher.start()
    """

    def __init__(
        self,
        store: LabelStore,
        on_promote: Callable[[str], None],
        on_status: Callable[[TrainerStatus], None] | None = None,
        interval: float = 1.0,
    ) -> None:
        self.store = store
        self.on_promote = on_promote
        self.on_status = on_status
        self.interval = interval
        self._model: str | None = None
        self._model = self._active_model()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _active_model(self) -> str | None:
        try:
            return self.store.trainer.view().active_model
        except Exception:  # the store is busy or closing: nothing new this time
            return self._model

    def poll(self) -> None:
        """One look at the store (the thread calls this every ``interval`` seconds)."""
        model = self._active_model()
        if model is not None and model != self._model:
            self._model = model
            with contextlib.suppress(Exception):
                self.on_promote(model)
        if self.on_status is not None:
            with contextlib.suppress(Exception):
                self.on_status(trainer_status(self.store))

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, daemon=True, name="trainer-watch")
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            self.poll()
