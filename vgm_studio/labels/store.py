"""The label store: one SQLite database (WAL) per workspace that never loses a label.

Every label, skip and undo is its own committed transaction, appended to ``events``; the
``labels`` table is the current state derived from those events in the same transaction, so a
process killed at any instant leaves both consistent. Labels are keyed by the stable
``edge_id`` and by annotator: candidates made again from the same log keep their labels, and
two annotators who disagree are both kept (a conflict).

The store is sealed: it hands out records (``records.py``), never a connection; model
versions and the trainer's tables are its ``versions`` and ``trainer`` parts. It is the
SQLite implementation of ``repository.LabelRepository``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.errors import InputError
from vgm_studio.labels.claims import Claims
from vgm_studio.labels.database import DB_NAME, HINT, Database, now
from vgm_studio.labels.records import Event, LabelRecord, Predictions
from vgm_studio.labels.repository import LabelRepository
from vgm_studio.labels.schema import aware
from vgm_studio.labels.trainer_tables import TrainerTables
from vgm_studio.labels.versions import ModelVersions, set_predictions
from vgm_studio.matching.edges import Edge

HUMAN_LABELS: tuple[str, ...] = ("success", "failure")

__all__ = ["DB_NAME", "HUMAN_LABELS", "Event", "LabelRecord", "LabelStore", "Predictions", "now"]


class LabelStore:
    """A workspace's label store. Safe to share between threads; open it once per process.

    Args:
        workspace: The workspace folder; made, with its database, when missing.
        create: Make the workspace when it does not exist (else refuse).
        durable: Flush every commit to disk (``synchronous=FULL``). The trainer, which
            writes no labels, opens its store without it: its frequent status writes then
            cost no disk flush that the app's label commits would queue behind.

    Attributes:
        versions: The workspace's model versions.
        trainer: The background trainer's state, requests and held-out split.
        claims: Which unlabelled edges the studio servers on this workspace have handed out.

    Raises:
        InputError: The folder holds a database made by another version, or not by us.
    """

    def __init__(self, workspace: str | Path, *, create: bool = True, durable: bool = True) -> None:
        self.workspace = Path(workspace)
        self.path = self.workspace / DB_NAME
        if self.workspace.exists() and not self.workspace.is_dir():
            raise InputError(self.workspace, "is a file; a workspace is a folder")
        if not self.path.exists() and not create:
            raise InputError(self.workspace, f"no workspace here (no {DB_NAME})")
        try:
            self.workspace.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(self.path, f"cannot open the label store ({exc}){HINT}") from None
        self._db = Database(self.path, durable, writable=create)
        self.versions = ModelVersions(self._db, self.workspace)
        self.trainer = TrainerTables(self._db)
        self.claims = Claims(self._db)

    def close(self) -> None:
        self._db.close()

    def _query(self, sql: str, args: Iterable[Any] = ()) -> list[Any]:
        return self._db.query(sql, args)

    # -- sources and edges -------------------------------------------------------------

    def has_source(self, sha256: str) -> bool:
        return bool(self._query("SELECT 1 FROM sources WHERE sha256 = ?", (sha256,)))

    def add_edges(self, edges: Iterable[Edge], source: tuple[str, str, str] | None = None) -> int:
        """Adds edges not yet in the store (by ``edge_id``), after those already there.

        Args:
            edges: The edges, in the order they should be shown.
            source: ``(sha256, path, kind)`` of the file they came from, so it is not redone.

        Returns:
            How many edges were new.
        """
        with self._db.transaction() as db:
            start = db.execute("SELECT COALESCE(MAX(position), -1) + 1 FROM edges").fetchone()[0]
            added = 0
            for edge in edges:
                cur = db.execute(
                    "INSERT OR IGNORE INTO edges VALUES (?, ?, ?, ?, ?)",
                    (
                        edge.edge_id,
                        start + added,
                        edge.kind,
                        edge.label,
                        json.dumps(edge.to_json(), separators=(",", ":")),
                    ),
                )
                added += cur.rowcount
            if source is not None:
                db.execute(
                    "INSERT OR REPLACE INTO sources VALUES (?, ?, ?, ?, ?)",
                    (*source, added, now()),
                )
        return added

    def edge_ids(self) -> list[str]:
        """Every edge id, in log order."""
        return [r[0] for r in self._query("SELECT edge_id FROM edges ORDER BY position")]

    def edge(self, edge_id: str) -> Edge:
        rows = self._query("SELECT body FROM edges WHERE edge_id = ?", (edge_id,))
        if not rows:
            raise KeyError(edge_id)
        return Edge.from_json(json.loads(rows[0][0]), self.path)

    def edges(self) -> list[Edge]:
        rows = self._query("SELECT body FROM edges ORDER BY position")
        return [Edge.from_json(json.loads(r[0]), self.path) for r in rows]

    def count_edges(self) -> int:
        return int(self._query("SELECT COUNT(*) FROM edges")[0][0])

    # -- labels ------------------------------------------------------------------------

    def label(self, edge_id: str, annotator: str, label: str, note: str = "") -> Event:
        """Records one annotator's label of one edge, committed before this returns."""
        if label not in HUMAN_LABELS:
            raise ValueError(f"label must be one of {HUMAN_LABELS}, not {label!r}")
        return self._append(edge_id, annotator, "label", label, note)

    def skip(self, edge_id: str, annotator: str) -> Event:
        """Records that an annotator passed over an edge; the edge's labels do not change."""
        with self._db.transaction() as db:
            made_at = now()
            cur = db.execute(
                "INSERT INTO events (edge_id, annotator, action, made_at) VALUES (?, ?, 'skip', ?)",
                (edge_id, annotator, made_at),
            )
            event_id = cur.lastrowid
        assert event_id is not None
        return Event(event_id, edge_id, annotator, "skip", None, "", made_at, None)

    def _append(
        self,
        edge_id: str,
        annotator: str,
        action: str,
        label: str | None,
        note: str,
        undoes: int | None = None,
        labeled_at: str | None = None,
        restores: int | None = None,
    ) -> Event:
        made_at = now()
        with self._db.transaction() as db:
            prev = db.execute(
                "SELECT label, note, labeled_at, event_id FROM labels "
                "WHERE edge_id = ? AND annotator = ?",
                (edge_id, annotator),
            ).fetchone()
            cur = db.execute(
                "INSERT INTO events (edge_id, annotator, action, label, note, made_at, undoes, "
                "prev_label, prev_note, prev_labeled_at, prev_event) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (edge_id, annotator, action, label, note, made_at, undoes, *(prev or (None,) * 4)),
            )
            event_id = cur.lastrowid
            # An undo restores the earlier state under the event that made it, so that event
            # can be undone in turn.
            state_event = restores if restores is not None else event_id
            if label is None:
                db.execute(
                    "DELETE FROM labels WHERE edge_id = ? AND annotator = ?", (edge_id, annotator)
                )
            else:
                db.execute(
                    "INSERT OR REPLACE INTO labels VALUES (?, ?, ?, ?, ?, ?)",
                    (edge_id, annotator, label, note, labeled_at or made_at, state_event),
                )
        assert event_id is not None
        return Event(event_id, edge_id, annotator, action, label, note, made_at, undoes)

    def undo(self, event_id: int) -> Event:
        """Takes back a label event by appending one that restores the state before it.

        Raises:
            ValueError: The event is not a label, was undone already, or was overtaken by a
                later label of the same annotator on the same edge.
        """
        with self._db.transaction() as db:
            row = db.execute(
                "SELECT edge_id, annotator, action, prev_label, prev_note, prev_labeled_at, "
                "prev_event FROM events WHERE id = ?",
                (event_id,),
            ).fetchone()
            if row is None or row[2] not in ("label", "import"):
                raise ValueError(f"event {event_id} is not a label that can be undone")
            if db.execute("SELECT 1 FROM events WHERE undoes = ?", (event_id,)).fetchone():
                raise ValueError(f"event {event_id} was undone already")
            edge_id, annotator, _, prev_label, prev_note, prev_at, prev_event = row
            current = db.execute(
                "SELECT event_id FROM labels WHERE edge_id = ? AND annotator = ?",
                (edge_id, annotator),
            ).fetchone()
            if current is None or current[0] != event_id:
                raise ValueError(f"event {event_id} was overtaken by a later label")
            # Nested in the same transaction: the undo and its state change commit together.
            return self._append(
                edge_id,
                annotator,
                "undo",
                prev_label,
                prev_note or "",
                undoes=event_id,
                labeled_at=prev_at,
                restores=prev_event,
            )

    def import_label(self, record: LabelRecord) -> bool:
        """Adds a label made elsewhere (an export); the newer of it and the store's wins.

        Returns:
            Whether the store changed.
        """
        with self._db.transaction() as db:
            row = db.execute(
                "SELECT label, note, labeled_at FROM labels WHERE edge_id = ? AND annotator = ?",
                (record.edge_id, record.annotator),
            ).fetchone()
            # As instants, not text: "13:00+05:00" is earlier than "12:00+00:00".
            if row is not None and aware(row[2]) >= aware(record.labeled_at):
                return False
            self._append(
                record.edge_id,
                record.annotator,
                "import",
                record.label,
                record.note,
                labeled_at=record.labeled_at,
            )
            return True

    def import_all(self, edges: Iterable[Edge], records: Iterable[LabelRecord]) -> tuple[int, int]:
        """Adds an export's edges and labels in one transaction: all of them or, if anything
        fails on the way, none.

        Returns:
            (edges added, labels added or updated).
        """
        with self._db.transaction():
            added = self.add_edges(edges)
            changed = sum(self.import_label(r) for r in records)
        return added, changed

    def labels(self, edge_id: str | None = None) -> list[LabelRecord]:
        """Current labels, all or one edge's, in edge then annotator order."""
        sql = (
            "SELECT l.edge_id, annotator, label, note, labeled_at FROM labels l "
            "JOIN edges e USING (edge_id)"
        )
        args: tuple[str, ...] = ()
        if edge_id is not None:
            sql += " WHERE l.edge_id = ?"
            args = (edge_id,)
        rows = self._query(sql + " ORDER BY e.position, annotator", args)
        return [LabelRecord(*r) for r in rows]

    def label_map(self) -> dict[str, dict[str, str]]:
        """edge_id → {annotator: label}, for queues and counts."""
        out: dict[str, dict[str, str]] = {}
        for edge_id, annotator, label in self._query(
            "SELECT edge_id, annotator, label FROM labels"
        ):
            out.setdefault(edge_id, {})[annotator] = label
        return out

    def reference_labels(self) -> dict[str, str]:
        rows = self._query(
            "SELECT edge_id, reference_label FROM edges WHERE reference_label IS NOT NULL"
        )
        return dict(rows)

    def history(self, edge_id: str | None = None) -> list[Event]:
        """The appended events, oldest first."""
        sql = "SELECT id, edge_id, annotator, action, label, note, made_at, undoes FROM events"
        if edge_id is None:
            return [Event(*r) for r in self._query(sql + " ORDER BY id")]
        return [Event(*r) for r in self._query(sql + " WHERE edge_id = ? ORDER BY id", (edge_id,))]

    # -- predictions -------------------------------------------------------------------

    def set_predictions(
        self, model: str, probabilities: dict[str, float], threshold: float = DEFAULT_THRESHOLD
    ) -> None:
        """Stores a model's p(success) per edge and makes it the active model.

        Args:
            model: A name that tells model versions apart.
            probabilities: edge_id → p(success).
            threshold: p(success) at or above which the model says success.
        """
        with self._db.transaction() as db:
            set_predictions(db, model, probabilities, threshold)

    def predictions(self) -> Predictions:
        """The active model's predictions (empty when there is none)."""
        meta = dict(
            self._query(
                "SELECT key, value FROM meta WHERE key IN ('active_model', 'active_threshold')"
            )
        )
        model = meta.get("active_model")
        if model is None:
            return Predictions(None, DEFAULT_THRESHOLD, {})
        rows = self._query("SELECT edge_id, p FROM predictions WHERE model = ?", (model,))
        return Predictions(
            model, float(meta.get("active_threshold", DEFAULT_THRESHOLD)), dict(rows)
        )


def _implements(store: LabelStore) -> LabelRepository:
    """Never called: mypy checks here that the SQLite store implements the interface."""
    return store
