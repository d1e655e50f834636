"""Model versions and trainer state, kept in the workspace's label store.

Versions live in the store's ``models`` table, their checkpoints in ``WORKSPACE/models/vN.pt``.
A checkpoint is complete on disk before its row exists: ``register_model`` moves the finished
file into place and inserts the row, the promotion and the predictions in one transaction, so
a trainer killed at any instant leaves either a whole registered version or an unregistered
file that ``remove_orphans`` deletes later. The trainer's progress and the app's training
requests are small tables of their own, made here when missing.
"""

from __future__ import annotations

import json
import os
import re
import socket
import sqlite3
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast

from vgm_studio.labels.store import LabelStore, now

State = Literal["idle", "training", "stopped", "crashed"]
STATES: tuple[str, ...] = ("idle", "training", "stopped", "crashed")
MODELS_DIR = "models"
_VERSION_NAME = re.compile(r"^v(\d+)$")

_TABLES = """
CREATE TABLE IF NOT EXISTS trainer_state (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS train_requests (
    id INTEGER PRIMARY KEY AUTOINCREMENT, requested_at TEXT NOT NULL,
    from_scratch INTEGER NOT NULL, done_at TEXT);
CREATE TABLE IF NOT EXISTS trainer_split (
    edge_id TEXT PRIMARY KEY, held_out INTEGER NOT NULL)
"""
# Stores whose connection has seen the tables: made once per store, not once per status poll
# (a CREATE is a write, and the app polls every second).
_READY: weakref.WeakSet[LabelStore] = weakref.WeakSet()


def ensure_tables(store: LabelStore) -> None:
    """Makes the trainer's tables in the store when they are missing."""
    if store in _READY:
        return
    with store.transaction() as db:
        for statement in _TABLES.split(";"):
            if statement.strip():
                db.execute(statement)
    _READY.add(store)


@dataclass(frozen=True)
class ModelRecord:
    """One registered model version.

    Attributes:
        version: N of ``vN``.
        path: The checkpoint, ``WORKSPACE/models/vN.pt``.
        created_at: When it was registered (UTC, ISO 8601).
        metrics: Held-out figures and how the version was trained (see the worker).
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
class TrainerStatus:
    """What the app shows about the trainer.

    Attributes:
        state: ``idle``, ``training``, ``stopped`` or ``crashed``.
        epoch: Epochs done in the current training (0 when not training).
        epochs: Epochs planned for it.
        metrics: Held-out metrics of the active version ({} without one).
        labels_since: Labels made since the data of the last version was read.
        active_version: N of the active ``vN``, or None (no model, or one not trained here).
        updated_at: When the trainer last reported (UTC, ISO 8601), or None.
        message: The trainer's last words: why it waits, what it registered, how it died.
        pending_request: A "Train now" request is waiting.
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


def model_path(workspace: Path, version: int) -> Path:
    return Path(workspace) / MODELS_DIR / f"v{version}.pt"


def version_of(model_name: str | None) -> int | None:
    """N for a prediction key ``vN``; None for other models (a bundled one, say)."""
    match = _VERSION_NAME.match(model_name or "")
    return int(match.group(1)) if match else None


def _row_to_record(row: tuple[Any, ...], workspace: Path, active: int | None) -> ModelRecord:
    version, path, created_at, metrics, labels_seen, seconds, promoted = row
    return ModelRecord(
        version=int(version),
        path=workspace / path,
        created_at=created_at,
        metrics=json.loads(metrics),
        labels_seen=int(labels_seen),
        seconds=float(seconds),
        promoted=bool(promoted),
        active=version == active,
    )


def _active(db: sqlite3.Connection) -> int | None:
    row = db.execute("SELECT value FROM meta WHERE key = 'active_model'").fetchone()
    version = version_of(row[0] if row else None)
    if version is None:
        return None
    known = db.execute("SELECT 1 FROM models WHERE version = ?", (version,)).fetchone()
    return version if known else None


def active_version(store: LabelStore) -> int | None:
    """N of the version whose predictions the app shows; None when that is no version of ours."""
    with store.snapshot() as db:
        return _active(db)


def list_models(store: LabelStore) -> list[ModelRecord]:
    """Every registered version, oldest first."""
    with store.snapshot() as db:
        active = _active(db)
        rows = db.execute(
            "SELECT version, path, created_at, metrics, labels_seen, seconds, promoted "
            "FROM models ORDER BY version"
        ).fetchall()
    return [_row_to_record(r, store.workspace, active) for r in rows]


def get_model(store: LabelStore, version: int) -> ModelRecord | None:
    return next((m for m in list_models(store) if m.version == version), None)


def register_model(
    store: LabelStore,
    checkpoint_path: Path,
    metrics: dict[str, Any],
    labels_seen: int,
    seconds: float,
    promote: bool,
    predictions: dict[str, float] | None = None,
    threshold: float = 0.5,
    state: dict[str, str] | None = None,
) -> int:
    """Registers a finished checkpoint as the next version ``vN``.

    The file is moved to ``models/vN.pt`` (a rename: it is whole or absent) inside the same
    transaction that inserts its row, marks the promotion, stores its predictions and makes it
    active; a process killed part way leaves at most an unregistered file.

    Args:
        store: The workspace's store.
        checkpoint_path: A complete checkpoint on the same file system, under ``models/``
            (written with ``write_checkpoint``); it is moved, not copied.
        metrics: Held-out figures and training facts, kept as JSON.
        labels_seen: Workspace edges with a human label the version saw.
        seconds: Wall time of its training.
        promote: Make it the active model (needs ``predictions``).
        predictions: edge_id → p(success), stored under ``vN`` when promoted.
        threshold: p(success) at or above which it says success.
        state: Trainer-state keys to write in the same transaction (the worker's watermark).

    Returns:
        N.
    """
    if promote and predictions is None:
        raise ValueError("a promoted version needs its predictions")
    ensure_tables(store)
    with store.transaction() as db:
        version = db.execute("SELECT COALESCE(MAX(version), 0) + 1 FROM models").fetchone()[0]
        target = model_path(store.workspace, version)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(checkpoint_path, target)
        _fsync_dir(target.parent)
        db.execute(
            "INSERT INTO models VALUES (?, ?, ?, ?, ?, ?, ?)",
            (
                version,
                str(target.relative_to(store.workspace)),
                now(),
                json.dumps(metrics, allow_nan=True),
                labels_seen,
                float(seconds),
                int(promote),
            ),
        )
        if promote:
            assert predictions is not None
            store.set_predictions(f"v{version}", predictions, threshold)  # nested: same commit
        _write_state(db, state or {})
    return int(version)


def _fsync_dir(folder: Path) -> None:
    """Makes a rename in ``folder`` survive a power cut, not only a kill."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def remove_orphans(store: LabelStore) -> list[Path]:
    """Deletes checkpoint files no version row names: left by a trainer killed mid-write.

    Returns:
        The files deleted.
    """
    folder = store.workspace / MODELS_DIR
    if not folder.is_dir():
        return []
    with store.transaction() as db:
        known = {Path(r[0]).name for r in db.execute("SELECT path FROM models").fetchall()}
        removed = []
        for path in folder.iterdir():
            if path.is_file() and path.suffix == ".pt" and path.name not in known:
                path.unlink(missing_ok=True)
                removed.append(path)
    return removed


# -- requests ------------------------------------------------------------------------------


def request_training(store: LabelStore, from_scratch: bool = False) -> int:
    """Asks the trainer to train now (the app's "Train now"); returns the request's id."""
    ensure_tables(store)
    with store.transaction() as db:
        cur = db.execute(
            "INSERT INTO train_requests (requested_at, from_scratch) VALUES (?, ?)",
            (now(), int(from_scratch)),
        )
    assert cur.lastrowid is not None
    return int(cur.lastrowid)


def pending_requests(store: LabelStore) -> list[tuple[int, bool]]:
    """(id, from_scratch) of requests not yet served, oldest first."""
    ensure_tables(store)
    with store.snapshot() as db:
        rows = db.execute(
            "SELECT id, from_scratch FROM train_requests WHERE done_at IS NULL ORDER BY id"
        ).fetchall()
    return [(int(i), bool(s)) for i, s in rows]


def finish_requests(db: sqlite3.Connection, up_to: int) -> None:
    """Marks requests up to id ``up_to`` served (inside the caller's transaction)."""
    db.execute(
        "UPDATE train_requests SET done_at = ? WHERE done_at IS NULL AND id <= ?", (now(), up_to)
    )


# -- trainer state -------------------------------------------------------------------------


def _write_state(db: sqlite3.Connection, values: dict[str, str]) -> None:
    if not values:
        return
    values = {**values, "updated_at": now()}
    db.executemany("INSERT OR REPLACE INTO trainer_state VALUES (?, ?)", list(values.items()))


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
    ensure_tables(store)
    values = {"state": state, "epoch": str(epoch), "epochs": str(epochs)}
    if message is not None:
        values["message"] = message
    if pid is not None:
        values |= {"pid": str(pid), "host": socket.gethostname()}
    with store.transaction() as db:
        _write_state(db, values)


def read_state(store: LabelStore) -> dict[str, str]:
    ensure_tables(store)
    with store.snapshot() as db:
        return dict(db.execute("SELECT key, value FROM trainer_state").fetchall())


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def labels_since(db: sqlite3.Connection, seen: int) -> int:
    """Labels made (or imported) after event ``seen``: what the next version has not read."""
    row = db.execute(
        "SELECT COUNT(*) FROM events WHERE id > ? AND action IN ('label', 'import')", (seen,)
    ).fetchone()
    return int(row[0])


def trainer_status(store: LabelStore) -> TrainerStatus:
    """The trainer's state for the app's panel; cheap enough to poll every second."""
    ensure_tables(store)
    with store.snapshot() as db:
        state = dict(db.execute("SELECT key, value FROM trainer_state").fetchall())
        active = _active(db)
        metrics_row = db.execute(
            "SELECT metrics FROM models WHERE version = ?", (active,)
        ).fetchone()
        since = labels_since(db, int(state.get("events_seen", "0")))
        pending = db.execute(
            "SELECT 1 FROM train_requests WHERE done_at IS NULL LIMIT 1"
        ).fetchone()
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
        metrics=json.loads(metrics_row[0]) if metrics_row else {},
        labels_since=since,
        active_version=active,
        updated_at=state.get("updated_at"),
        message=state.get("message", ""),
        pending_request=pending is not None,
    )
