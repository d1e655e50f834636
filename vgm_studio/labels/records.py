"""What the label store hands out: plain records, never a connection."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vgm_studio.core.decision import DEFAULT_THRESHOLD


@dataclass(frozen=True)
class LabelRecord:
    """One annotator's current label of one edge."""

    edge_id: str
    annotator: str
    label: str
    note: str
    labeled_at: str


@dataclass(frozen=True)
class Predictions:
    """The active model's p(success) per edge, and the threshold it decides at."""

    model: str | None
    threshold: float
    p: dict[str, float]


@dataclass(frozen=True)
class Event:
    """One appended history row: what an annotator did, and the state it left."""

    id: int
    edge_id: str
    annotator: str
    action: str
    label: str | None
    note: str
    made_at: str
    undoes: int | None


@dataclass(frozen=True)
class ModelRecord:
    """One registered model version.

    Attributes:
        version: N of ``vN``.
        path: The checkpoint, ``WORKSPACE/models/vN.pt``.
        created_at: When it was registered (UTC, ISO 8601).
        metrics: Held-out figures and how the version was trained (see the trainer).
        labels_seen: Workspace edges with a human label it was trained and held out on.
        seconds: Wall time of its training cycle, predictions included.
        promoted: Whether it was promoted (made the active model) when registered.
        active: Whether it is the model in use now.
    """

    version: int
    path: Path
    created_at: str
    metrics: dict[str, Any]
    labels_seen: int
    seconds: float
    promoted: bool
    active: bool

    @property
    def name(self) -> str:
        return f"v{self.version}"


@dataclass(frozen=True)
class NewVersion:
    """A finished checkpoint to register as the next version, and what comes with it.

    Attributes:
        checkpoint: A complete checkpoint file under the workspace's ``models/`` folder; it
            is moved into place, not copied.
        metrics: Held-out figures and training facts, kept as JSON.
        labels_seen: Workspace edges with a human label the version saw.
        seconds: Wall time of its training.
        promote: Make it the active model (needs ``predictions``).
        predictions: edge_id → p(success), stored under ``vN`` when promoted.
        threshold: p(success) at or above which it says success.
        state: Trainer-state keys written in the same transaction (the trainer's watermark).
        requests_served: Training requests up to this id are marked served with it (0: none).
    """

    checkpoint: Path
    metrics: dict[str, Any]
    labels_seen: int
    seconds: float
    promote: bool
    predictions: dict[str, float] | None = None
    threshold: float = DEFAULT_THRESHOLD
    state: dict[str, str] | None = None
    requests_served: int = 0


@dataclass(frozen=True)
class TrainerView:
    """The trainer's tables read at one moment, for its status line.

    Attributes:
        state: The trainer's last report (state, epoch, epochs, message, pid, host, …).
        active_version: N of the active ``vN`` (None: no version of ours is in use).
        active_metrics: That version's metrics ({} without one).
        active_model: The model whose predictions are in use (None: none).
        labels_since: Labels made after the last version's data was read, not undone.
        pending_request: A training request is waiting.
    """

    state: dict[str, str]
    active_version: int | None
    active_metrics: dict[str, Any]
    active_model: str | None
    labels_since: int
    pending_request: bool
