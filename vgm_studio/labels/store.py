"""The label store: one SQLite database (WAL) per workspace that never loses a label.

Every label, skip and undo is its own committed transaction, appended to ``events``; the
``labels`` table is the current state derived from those events in the same transaction, so a
process killed at any instant leaves both consistent. Labels are keyed by the stable
``edge_id`` and by annotator: candidates made again from the same log keep their labels, and
two annotators who disagree are both kept (a conflict).
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Iterable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from vgm_studio import __version__
from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.errors import InputError
from vgm_studio.labels.check import check_workspace, check_writable
from vgm_studio.labels.schema import aware
from vgm_studio.matching.edges import Edge

SCHEMA = 1
FORMAT = "vgm-studio-workspace"
DB_NAME = "labels.sqlite"
HUMAN_LABELS: tuple[str, ...] = ("success", "failure")
_HINT = "; the workspace folder and its files must be writable (not read-only or immutable)"

_TABLES = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE sources (
    sha256 TEXT PRIMARY KEY, path TEXT NOT NULL, kind TEXT NOT NULL,
    edges INTEGER NOT NULL, added_at TEXT NOT NULL);
CREATE TABLE edges (
    edge_id TEXT PRIMARY KEY, position INTEGER NOT NULL UNIQUE, kind TEXT NOT NULL,
    reference_label TEXT, body TEXT NOT NULL);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    edge_id TEXT NOT NULL REFERENCES edges(edge_id),
    annotator TEXT NOT NULL,
    action TEXT NOT NULL CHECK (action IN ('label', 'skip', 'undo', 'import')),
    label TEXT CHECK (label IN ('success', 'failure')),
    note TEXT NOT NULL DEFAULT '',
    made_at TEXT NOT NULL,
    undoes INTEGER REFERENCES events(id),
    prev_label TEXT, prev_note TEXT, prev_labeled_at TEXT, prev_event INTEGER);
CREATE TABLE labels (
    edge_id TEXT NOT NULL REFERENCES edges(edge_id),
    annotator TEXT NOT NULL,
    label TEXT NOT NULL CHECK (label IN ('success', 'failure')),
    note TEXT NOT NULL,
    labeled_at TEXT NOT NULL,
    event_id INTEGER NOT NULL REFERENCES events(id),
    PRIMARY KEY (edge_id, annotator));
CREATE TABLE models (
    version INTEGER PRIMARY KEY, path TEXT NOT NULL, created_at TEXT NOT NULL,
    metrics TEXT NOT NULL, labels_seen INTEGER NOT NULL, seconds REAL NOT NULL,
    promoted INTEGER NOT NULL DEFAULT 0);
CREATE TABLE predictions (
    edge_id TEXT NOT NULL REFERENCES edges(edge_id), model TEXT NOT NULL, p REAL NOT NULL,
    PRIMARY KEY (edge_id, model));
CREATE INDEX events_edge ON events (edge_id, annotator);
"""


def now() -> str:
    """UTC time as ISO 8601 with microseconds: sorts as text, and distinct clicks stay distinct."""
    return datetime.now(timezone.utc).isoformat(timespec="microseconds")


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


class LabelStore:
    """A workspace's label store. Safe to share between threads; open it once per process.

    Args:
        workspace: The workspace folder; made, with its database, when missing.
        create: Make the workspace when it does not exist (else refuse).
        durable: Flush every commit to disk (``synchronous=FULL``). The trainer, which
            writes no labels, opens its store without it: its frequent status writes then
            cost no disk flush that the app's label commits would queue behind.

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
            fresh = not self.path.exists()
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            # FULL: a label acknowledged on screen survives a power cut, not only a kill.
            self._db.execute(f"PRAGMA synchronous={'FULL' if durable else 'NORMAL'}")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.execute("PRAGMA busy_timeout=5000")
        except sqlite3.OperationalError as exc:  # read-only, immutable, locked: not damage
            raise InputError(self.path, f"cannot open the label store ({exc}){_HINT}") from None
        except sqlite3.DatabaseError as exc:
            raise InputError(self.path, f"not a VGM Studio workspace ({exc})") from None
        except (OSError, sqlite3.Error) as exc:
            raise InputError(self.path, f"cannot open the label store ({exc}){_HINT}") from None
        self._lock = threading.RLock()
        self._depth = 0
        if fresh:
            try:
                self._create()
            except sqlite3.OperationalError as exc:
                raise InputError(self.path, f"cannot make the label store ({exc}){_HINT}") from None
        self._check_version()
        check_workspace(self._db, self.path, _TABLES)
        if create:  # the commands that may make a store are those that write to it
            check_writable(self._db, self.path)

    def _create(self) -> None:
        with self.transaction() as db:
            for statement in _TABLES.split(";"):
                if statement.strip():
                    db.execute(statement)
            db.executemany(
                "INSERT INTO meta VALUES (?, ?)",
                [
                    ("format", FORMAT),
                    ("schema", str(SCHEMA)),
                    ("created_by", f"vgm-studio {__version__}"),
                    ("created_at", now()),
                ],
            )

    def _check_version(self) -> None:
        try:
            meta = dict(self._db.execute("SELECT key, value FROM meta").fetchall())
        except sqlite3.DatabaseError as exc:
            raise InputError(self.path, f"not a VGM Studio workspace ({exc})") from None
        if meta.get("format") != FORMAT:
            raise InputError(self.path, "not a VGM Studio workspace (no format mark)")
        if meta.get("schema") != str(SCHEMA):
            raise InputError(
                self.path,
                f"workspace made by {meta.get('created_by', 'another version')} with schema "
                f"{meta.get('schema')}; this vgm-studio {__version__} reads schema {SCHEMA}",
            )

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def transaction(self) -> AbstractContextManager[sqlite3.Connection]:
        """One committed transaction; rolled back whole if anything inside raises."""
        return self._begin("IMMEDIATE")

    def snapshot(self) -> AbstractContextManager[sqlite3.Connection]:
        """One consistent read-only view of the store.

        Unlike ``transaction`` it takes no write lock, so in WAL mode it never waits for
        another process's writer (the trainer storing a version): what polls the store
        from the app must not hold up a label behind someone else's commit.
        """
        return self._begin("DEFERRED")

    @contextmanager
    def _begin(self, mode: str) -> Iterator[sqlite3.Connection]:
        with self._lock:
            if self._depth:  # nested: part of the caller's transaction
                yield self._db
                return
            self._db.execute(f"BEGIN {mode}")
            self._depth += 1
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            else:
                self._db.execute("COMMIT")
            finally:
                self._depth -= 1

    def _query(self, sql: str, args: Iterable[Any] = ()) -> list[Any]:
        with self._lock:
            return self._db.execute(sql, tuple(args)).fetchall()

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
        with self.transaction() as db:
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
        return self._append(edge_id, annotator, "label", label, note, now())

    def skip(self, edge_id: str, annotator: str) -> Event:
        """Records that an annotator passed over an edge; the edge's labels do not change."""
        with self.transaction() as db:
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
        made_at: str,
        undoes: int | None = None,
        labeled_at: str | None = None,
        restores: int | None = None,
    ) -> Event:
        with self.transaction() as db:
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
        with self.transaction() as db:
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
                now(),
                undoes=event_id,
                labeled_at=prev_at,
                restores=prev_event,
            )

    def import_label(self, record: LabelRecord) -> bool:
        """Adds a label made elsewhere (an export); the newer of it and the store's wins.

        Returns:
            Whether the store changed.
        """
        with self.transaction() as db:
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
                now(),
                labeled_at=record.labeled_at,
            )
            return True

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
        with self.transaction() as db:
            db.execute("DELETE FROM predictions WHERE model = ?", (model,))
            db.executemany(
                "INSERT INTO predictions VALUES (?, ?, ?)",
                [(k, model, float(v)) for k, v in probabilities.items()],
            )
            db.execute("INSERT OR REPLACE INTO meta VALUES ('active_model', ?)", (model,))
            db.execute(
                "INSERT OR REPLACE INTO meta VALUES ('active_threshold', ?)", (str(threshold),)
            )

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
