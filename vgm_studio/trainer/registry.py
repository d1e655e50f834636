"""Model versions and trainer state, as the trainer and the app use them.

The rows live in the workspace's label store (``labels/versions.py``,
``labels/trainer_tables.py``), checkpoints in ``WORKSPACE/models/vN.pt``; this module gives
them the trainer's words: register a version, report progress, ask for training, and read the
status the app's panel shows (a trainer whose process died is ``crashed``, whatever it last
said).
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast

from vgm_studio.labels.records import ModelRecord, NewVersion
from vgm_studio.labels.store import LabelStore
from vgm_studio.labels.versions import MODELS_DIR, model_path, version_of

State = Literal["idle", "training", "stopped", "crashed"]
STATES: tuple[str, ...] = ("idle", "training", "stopped", "crashed")

__all__ = [
    "MODELS_DIR",
    "ModelRecord",
    "NewVersion",
    "State",
    "TrainerStatus",
    "active_version",
    "get_model",
    "list_models",
    "model_path",
    "pending_requests",
    "read_state",
    "register_model",
    "remove_orphans",
    "report",
    "request_training",
    "trainer_status",
    "version_of",
]


@dataclass(frozen=True)
class TrainerStatus:
    """What the app shows about the trainer.

    Attributes:
        state: ``idle``, ``training``, ``stopped`` or ``crashed``.
        epoch: Epochs done in the current training (0 when not training).
        epochs: Epochs planned for it.
        metrics: Held-out metrics of the active version ({} without one).
        labels_since: Labels made since the data of the last version was read, not undone.
        active_version: N of the active ``vN``, or None (no model, or one not trained here).
        updated_at: When the trainer last reported (UTC, ISO 8601), or None.
        message: The trainer's last words: why it waits, what it registered, how it died.
        pending_request: A "Train now" request is waiting.
        active_model: The model whose predictions are shown: ``vN`` or another model's
            name (the bundled one's, say); None without predictions.
    """

    state: State
    epoch: int
    epochs: int
    metrics: dict[str, Any]
    labels_since: int
    active_version: int | None
    updated_at: str | None
    message: str
    pending_request: bool
    active_model: str | None = None


def active_version(store: LabelStore) -> int | None:
    """N of the version whose predictions the app shows; None when that is no version of ours."""
    return store.versions.active()


def list_models(store: LabelStore) -> list[ModelRecord]:
    """Every registered version, oldest first."""
    return store.versions.all()


def get_model(store: LabelStore, version: int) -> ModelRecord | None:
    return next((m for m in list_models(store) if m.version == version), None)


def register_model(store: LabelStore, new: NewVersion) -> int:
    """Registers a finished checkpoint as the next version ``vN`` (see ``NewVersion``).

    The version, its promotion and predictions, the trainer-state keys and the requests it
    serves are stored in one transaction; the file is moved to ``models/vN.pt`` inside it.

    Returns:
        N.
    """
    return store.versions.register(new)


def remove_orphans(store: LabelStore) -> list[Path]:
    """Deletes checkpoint files no version names (a trainer killed mid-write); returns them."""
    return store.versions.remove_orphans()


def request_training(store: LabelStore, from_scratch: bool = False) -> int:
    """Asks the trainer to train now (the app's "Train now"); returns the request's id."""
    return store.trainer.request(from_scratch)


def pending_requests(store: LabelStore) -> list[tuple[int, bool]]:
    """(id, from_scratch) of requests not yet served, oldest first."""
    return store.trainer.pending()


def report(
    store: LabelStore,
    state: State,
    *,
    epoch: int = 0,
    epochs: int = 0,
    message: str | None = None,
    pid: int | None = None,
) -> None:
    """The trainer's progress writer: one small committed transaction per call.

    Args:
        store: The workspace's store.
        state: What the trainer is doing.
        epoch: Epochs done (training only).
        epochs: Epochs planned (training only).
        message: A line for the app; None keeps the last one.
        pid: The reporting process; None keeps the last one.
    """
    values = {"state": str(state), "epoch": str(epoch), "epochs": str(epochs)}
    if message is not None:
        values["message"] = message
    if pid is not None:
        values["pid"] = str(pid)
    store.trainer.report(values, with_host=pid is not None)


def read_state(store: LabelStore) -> dict[str, str]:
    return store.trainer.state()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def trainer_status(store: LabelStore) -> TrainerStatus:
    """The trainer's state for the app's panel; cheap enough to poll every second."""
    view = store.trainer.view()
    state = view.state
    name = state.get("state", "stopped")
    # A trainer killed outright cannot say so; its process being gone says it for it.
    pid = int(state.get("pid", "0"))
    if (
        name in ("idle", "training")
        and pid
        and state.get("host") == socket.gethostname()
        and not _alive(pid)
    ):
        name = "crashed"
    return TrainerStatus(
        state=cast(State, name if name in STATES else "stopped"),
        epoch=int(state.get("epoch", "0")),
        epochs=int(state.get("epochs", "0")),
        metrics=view.active_metrics,
        labels_since=view.labels_since,
        active_version=view.active_version,
        updated_at=state.get("updated_at"),
        message=state.get("message", ""),
        pending_request=view.pending_request,
        active_model=view.active_model,
    )
