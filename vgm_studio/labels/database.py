"""The workspace's SQLite database: its schema, its connection, its transactions.

Private to ``labels/``: the stores in this package are the only code that writes SQL, and
none of them hands a connection out. A second backend (PostgreSQL, say) replaces this module
and the stores' queries, not their interface (``repository.py``).
"""

from __future__ import annotations

import os
import sqlite3
import threading
from collections.abc import Iterable, Iterator
from contextlib import AbstractContextManager, contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from vgm_studio import __version__
from vgm_studio.errors import InputError
from vgm_studio.labels.check import check_workspace, check_writable

SCHEMA = 1
FORMAT = "vgm-studio-workspace"
DB_NAME = "labels.sqlite"
HINT = "; the workspace folder and its files must be writable (not read-only or immutable)"

TABLES = """
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
# The trainer's tables came after schema 1 was fixed; made when missing, in any workspace.
TRAINER_TABLES = """
CREATE TABLE IF NOT EXISTS trainer_state (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS train_requests (
    id INTEGER PRIMARY KEY AUTOINCREMENT, requested_at TEXT NOT NULL,
    from_scratch INTEGER NOT NULL, done_at TEXT);
CREATE TABLE IF NOT EXISTS trainer_split (
    edge_id TEXT PRIMARY KEY, held_out INTEGER NOT NULL)
"""


def now() -> str:
    """UTC time as ISO 8601 with microseconds: sorts as text, and distinct clicks stay distinct."""
    return datetime.now(timezone.utc).isoformat(timespec="microseconds")


def fsync_dir(folder: Path) -> None:
    """Makes a rename in ``folder`` survive a power cut, not only a kill."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class Database:
    """One connection to a workspace's database, shared by threads under a lock.

    Args:
        path: The database file.
        durable: Flush every commit to disk (``synchronous=FULL``).

    Raises:
        InputError: Not a VGM Studio workspace, another schema, or it cannot be opened.
    """

    def __init__(self, path: Path, durable: bool = True, writable: bool = True) -> None:
        self.path = path
        try:
            fresh = not path.exists()
            self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            # FULL: a label acknowledged on screen survives a power cut, not only a kill.
            self._db.execute(f"PRAGMA synchronous={'FULL' if durable else 'NORMAL'}")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.execute("PRAGMA busy_timeout=5000")
        except sqlite3.OperationalError as exc:  # read-only, immutable, locked: not damage
            raise InputError(path, f"cannot open the label store ({exc}){HINT}") from None
        except sqlite3.DatabaseError as exc:
            raise InputError(path, f"not a VGM Studio workspace ({exc})") from None
        except (OSError, sqlite3.Error) as exc:
            raise InputError(path, f"cannot open the label store ({exc}){HINT}") from None
        self._lock = threading.RLock()
        self._depth = 0
        if fresh:
            try:
                self._create()
            except sqlite3.OperationalError as exc:
                raise InputError(path, f"cannot make the label store ({exc}){HINT}") from None
        self._check_version()
        check_workspace(self._db, path, TABLES)
        if writable:  # the commands that may make a store are those that write to it
            check_writable(self._db, path)
        self._trainer_tables_made = False

    def _create(self) -> None:
        with self.transaction() as db:
            _run_script(db, TABLES)
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

    def trainer_tables(self) -> None:
        """Makes the trainer's tables when missing: once per connection, since a CREATE is a
        write and the app polls the trainer's state every second."""
        if self._trainer_tables_made:
            return
        with self.transaction() as db:
            _run_script(db, TRAINER_TABLES)
        self._trainer_tables_made = True

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

    def query(self, sql: str, args: Iterable[Any] = ()) -> list[Any]:
        """The rows of one statement, outside any transaction of the caller's."""
        with self._lock:
            return self._db.execute(sql, tuple(args)).fetchall()


def _run_script(db: sqlite3.Connection, script: str) -> None:
    for statement in script.split(";"):
        if statement.strip():
            db.execute(statement)
