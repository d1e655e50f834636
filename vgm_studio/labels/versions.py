"""Model versions in the workspace: rows in ``models``, checkpoints in ``models/vN.pt``.

A checkpoint is complete on disk before its row exists: ``register`` moves the finished file
into place and inserts the row, the promotion, the predictions, the trainer's watermark and
the served requests in one transaction, so a trainer killed at any instant leaves either a
whole registered version or an unregistered file that ``remove_orphans`` deletes later.
"""

from __future__ import annotations

import json
import os
import re
import sqlite3
from pathlib import Path

from vgm_studio.labels.database import Database, fsync_dir, now
from vgm_studio.labels.records import ModelRecord, NewVersion

MODELS_DIR = "models"
_VERSION_NAME = re.compile(r"^v(\d+)$")


def version_of(model_name: str | None) -> int | None:
    """N for a prediction key ``vN``; None for other models (a bundled one, say)."""
    match = _VERSION_NAME.match(model_name or "")
    return int(match.group(1)) if match else None


def model_path(workspace: Path, version: int) -> Path:
    """Where version N's checkpoint lives."""
    return Path(workspace) / MODELS_DIR / f"v{version}.pt"


def active_in(db: sqlite3.Connection) -> int | None:
    """N of the version whose predictions are in use; None when that is no version of ours."""
    row = db.execute("SELECT value FROM meta WHERE key = 'active_model'").fetchone()
    version = version_of(row[0] if row else None)
    if version is None:
        return None
    known = db.execute("SELECT 1 FROM models WHERE version = ?", (version,)).fetchone()
    return version if known else None


def set_predictions(
    db: sqlite3.Connection, model: str, probabilities: dict[str, float], threshold: float
) -> None:
    """Stores a model's p(success) per edge and makes it the active model (in ``db``'s
    transaction)."""
    db.execute("DELETE FROM predictions WHERE model = ?", (model,))
    db.executemany(
        "INSERT INTO predictions VALUES (?, ?, ?)",
        [(k, model, float(v)) for k, v in probabilities.items()],
    )
    db.execute("INSERT OR REPLACE INTO meta VALUES ('active_model', ?)", (model,))
    db.execute("INSERT OR REPLACE INTO meta VALUES ('active_threshold', ?)", (str(threshold),))


def write_state(db: sqlite3.Connection, values: dict[str, str]) -> None:
    """Writes trainer-state keys (and when) in ``db``'s transaction."""
    if not values:
        return
    values = {**values, "updated_at": now()}
    db.executemany("INSERT OR REPLACE INTO trainer_state VALUES (?, ?)", list(values.items()))


def finish_requests(db: sqlite3.Connection, up_to: int) -> None:
    """Marks requests up to id ``up_to`` served (in ``db``'s transaction)."""
    db.execute(
        "UPDATE train_requests SET done_at = ? WHERE done_at IS NULL AND id <= ?", (now(), up_to)
    )


class ModelVersions:
    """A workspace's model versions.

    Args:
        database: The workspace's database.
        workspace: The workspace folder (checkpoints live under its ``models/``).
    """

    def __init__(self, database: Database, workspace: Path) -> None:
        self._db = database
        self.workspace = workspace

    def active(self) -> int | None:
        """N of the version whose predictions the app shows; None when that is no version."""
        with self._db.snapshot() as db:
            return active_in(db)

    def all(self) -> list[ModelRecord]:
        """Every registered version, oldest first."""
        with self._db.snapshot() as db:
            active = active_in(db)
            rows = db.execute(
                "SELECT version, path, created_at, metrics, labels_seen, seconds, promoted "
                "FROM models ORDER BY version"
            ).fetchall()
        return [self._record(r, active) for r in rows]

    def _record(self, row: tuple[object, ...], active: int | None) -> ModelRecord:
        version, path, created_at, metrics, labels_seen, seconds, promoted = row
        return ModelRecord(
            version=int(str(version)),
            path=self.workspace / str(path),
            created_at=str(created_at),
            metrics=json.loads(str(metrics)),
            labels_seen=int(str(labels_seen)),
            seconds=float(str(seconds)),
            promoted=bool(promoted),
            active=version == active,
        )

    def register(self, new: NewVersion) -> int:
        """Registers a finished checkpoint as the next version ``vN``; returns N.

        The file is moved to ``models/vN.pt`` (a rename: it is whole or absent) inside the
        transaction that inserts its row and, when promoted, its predictions; a process killed
        part way leaves at most an unregistered file.

        Raises:
            ValueError: A promotion without predictions.
        """
        if new.promote and new.predictions is None:
            raise ValueError("a promoted version needs its predictions")
        self._db.trainer_tables()
        with self._db.transaction() as db:
            version = db.execute("SELECT COALESCE(MAX(version), 0) + 1 FROM models").fetchone()[0]
            target = model_path(self.workspace, version)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(new.checkpoint, target)
            fsync_dir(target.parent)
            db.execute(
                "INSERT INTO models VALUES (?, ?, ?, ?, ?, ?, ?)",
                (
                    version,
                    str(target.relative_to(self.workspace)),
                    now(),
                    json.dumps(new.metrics, allow_nan=True),
                    new.labels_seen,
                    float(new.seconds),
                    int(new.promote),
                ),
            )
            if new.promote:
                assert new.predictions is not None
                set_predictions(db, f"v{version}", new.predictions, new.threshold)
            write_state(db, new.state or {})
            if new.requests_served:
                finish_requests(db, new.requests_served)
        return int(version)

    def remove_orphans(self) -> list[Path]:
        """Deletes checkpoint files no version row names: left by a trainer killed mid-write.

        Returns:
            The files deleted.
        """
        folder = self.workspace / MODELS_DIR
        if not folder.is_dir():
            return []
        with self._db.transaction() as db:
            known = {Path(r[0]).name for r in db.execute("SELECT path FROM models").fetchall()}
            removed = []
            for path in folder.iterdir():
                if path.is_file() and path.suffix == ".pt" and path.name not in known:
                    path.unlink(missing_ok=True)
                    removed.append(path)
        return removed
