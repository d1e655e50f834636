"""The team store's PostgreSQL connection: schema, dialect, transactions, locks and retries.

Private to ``labels/``; ``postgres.py`` builds the store on it. Split from it to keep each
module short: this half speaks to the server, that half is the store's interface.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any, TypeVar

import psycopg
import psycopg.sql

from vgm_studio import __version__
from vgm_studio.errors import InputError
from vgm_studio.labels.database import FORMAT, SCHEMA, now

# Advisory lock keys (any two 32-bit numbers that are ours): writers, and the one trainer.

_WRITE_LOCK = (0x56474D, 1)
_TRAINER_LOCK = (0x56474D, 2)
_EDGE_LOCKS = 0x56474E  # with hashtext(edge_id): one edge's label presses

TABLES = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE sources (
    sha256 TEXT PRIMARY KEY, path TEXT NOT NULL, kind TEXT NOT NULL,
    edges INTEGER NOT NULL, added_at TEXT NOT NULL);
CREATE TABLE edges (
    edge_id TEXT PRIMARY KEY, position INTEGER NOT NULL UNIQUE, kind TEXT NOT NULL,
    reference_label TEXT, body TEXT NOT NULL);
CREATE TABLE events (
    id BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    edge_id TEXT NOT NULL REFERENCES edges(edge_id),
    annotator TEXT NOT NULL,
    action TEXT NOT NULL CHECK (action IN ('label', 'skip', 'undo', 'import')),
    label TEXT CHECK (label IN ('success', 'failure')),
    note TEXT NOT NULL DEFAULT '',
    made_at TEXT NOT NULL,
    undoes BIGINT REFERENCES events(id),
    prev_label TEXT, prev_note TEXT, prev_labeled_at TEXT, prev_event BIGINT);
CREATE TABLE labels (
    edge_id TEXT NOT NULL REFERENCES edges(edge_id),
    annotator TEXT NOT NULL,
    label TEXT NOT NULL CHECK (label IN ('success', 'failure')),
    note TEXT NOT NULL,
    labeled_at TEXT NOT NULL,
    event_id BIGINT NOT NULL REFERENCES events(id),
    PRIMARY KEY (edge_id, annotator));
CREATE TABLE models (
    version INTEGER PRIMARY KEY, path TEXT NOT NULL, created_at TEXT NOT NULL,
    metrics TEXT NOT NULL, labels_seen INTEGER NOT NULL, seconds DOUBLE PRECISION NOT NULL,
    promoted INTEGER NOT NULL DEFAULT 0);
CREATE TABLE predictions (
    edge_id TEXT NOT NULL REFERENCES edges(edge_id), model TEXT NOT NULL,
    p DOUBLE PRECISION NOT NULL, PRIMARY KEY (edge_id, model));
CREATE INDEX events_edge ON events (edge_id, annotator);
CREATE INDEX events_undoes ON events (undoes);
CREATE TABLE IF NOT EXISTS trainer_state (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS train_requests (
    id BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY, requested_at TEXT NOT NULL,
    from_scratch INTEGER NOT NULL, done_at TEXT);
CREATE TABLE IF NOT EXISTS trainer_split (edge_id TEXT PRIMARY KEY, held_out INTEGER NOT NULL);
CREATE TABLE claims (
    edge_id TEXT PRIMARY KEY REFERENCES edges(edge_id), holder TEXT NOT NULL,
    until DOUBLE PRECISION NOT NULL)
"""
# Key columns of the tables written with INSERT OR REPLACE / OR IGNORE.
_KEYS = {
    "meta": ("key",),
    "trainer_state": ("key",),
    "sources": ("sha256",),
    "labels": ("edge_id", "annotator"),
    "edges": ("edge_id",),
    "trainer_split": ("edge_id",),
}
_COLUMNS = {
    "meta": ("key", "value"),
    "trainer_state": ("key", "value"),
    "sources": ("sha256", "path", "kind", "edges", "added_at"),
    "labels": ("edge_id", "annotator", "label", "note", "labeled_at", "event_id"),
}
_INSERT_OR = re.compile(r"^\s*INSERT OR (IGNORE|REPLACE) INTO (\w+)", re.IGNORECASE)
_RETURNS_ID = re.compile(r"^\s*INSERT INTO (events|train_requests)\b", re.IGNORECASE)
T = TypeVar("T")


def _dialect(sql: str) -> str:
    """The shared statement in PostgreSQL's spelling."""
    sql = sql.replace("?", "%s")
    match = _INSERT_OR.match(sql)
    if match:
        mode, table = match.group(1).upper(), match.group(2)
        sql = sql[: match.start()] + f"INSERT INTO {table}" + sql[match.end() :]
        keys = ", ".join(_KEYS[table])
        if mode == "IGNORE":
            sql += f" ON CONFLICT ({keys}) DO NOTHING"
        else:
            rest = [c for c in _COLUMNS[table] if c not in _KEYS[table]]
            sets = ", ".join(f"{c} = EXCLUDED.{c}" for c in rest)
            sql += f" ON CONFLICT ({keys}) DO UPDATE SET {sets}"
    elif _RETURNS_ID.match(sql):
        sql += " RETURNING id"
    return sql


class _Cursor:
    """The DB-API subset the shared statements use, over a psycopg cursor."""

    def __init__(self, cursor: psycopg.Cursor[Any], returns_id: bool) -> None:
        self._cursor = cursor
        self.rowcount = cursor.rowcount
        self.lastrowid: int | None = None
        if returns_id:
            row = cursor.fetchone()
            self.lastrowid = int(row[0]) if row else None

    def fetchone(self) -> Any:
        return self._cursor.fetchone()

    def fetchall(self) -> list[Any]:
        return self._cursor.fetchall()


class _Connection:
    def __init__(self, conn: psycopg.Connection[Any]) -> None:
        self._conn = conn

    def execute(self, sql: str, args: Sequence[Any] = ()) -> _Cursor:
        pg = _dialect(sql)
        cursor = self._conn.execute(pg, tuple(args))
        return _Cursor(cursor, pg.endswith("RETURNING id"))

    def executemany(self, sql: str, rows: Iterable[Sequence[Any]]) -> None:
        with self._conn.cursor() as cursor:
            cursor.executemany(_dialect(sql), [tuple(r) for r in rows])


class PgDatabase:
    """Connections to the team database, one per thread; the SQLite ``Database``'s interface.

    One per thread, not one shared under a lock as with SQLite: a label press then never
    queues behind another annotator's network round trips in the same server, and the
    server-side lock still serialises the writes.

    Args:
        url: ``postgresql://USER@HOST[:PORT]/DB``.
        retry_seconds: How long to wait for a server that went away before giving up.

    Raises:
        InputError: A bad URL, no server, or a database made by another version.
    """

    def __init__(self, url: str, retry_seconds: float = 30.0) -> None:
        self.url = url
        self.path = Path(url.split("@")[-1])  # for messages; never opened
        self.retry_seconds = retry_seconds
        self.reconnects = 0
        # Told a line while the server is away and None once it is back (the studio's panel).
        self.report: Callable[[str | None], None] = lambda _line: None
        self._local = threading.local()
        self._opened: list[psycopg.Connection[Any]] = []
        self._opened_lock = threading.Lock()
        self._conn = self._connect()
        self._prepare()

    @property
    def _conn(self) -> psycopg.Connection[Any]:
        conn: psycopg.Connection[Any] | None = getattr(self._local, "conn", None)
        if conn is None:
            conn = self._connect()
            self._conn = conn
        return conn

    @_conn.setter
    def _conn(self, conn: psycopg.Connection[Any]) -> None:
        self._local.conn = conn
        with self._opened_lock:
            self._opened.append(conn)

    @property
    def _depth(self) -> int:
        return int(getattr(self._local, "depth", 0))

    @_depth.setter
    def _depth(self, depth: int) -> None:
        self._local.depth = depth

    def _connect(self) -> psycopg.Connection[Any]:
        try:
            return psycopg.connect(self.url, autocommit=True, connect_timeout=5)
        except psycopg.ProgrammingError as exc:
            raise InputError(self.url, f"not a PostgreSQL URL ({_first_line(exc)})") from None
        except psycopg.OperationalError as exc:
            raise InputError(
                self.url, f"cannot reach the label store ({_first_line(exc)})"
            ) from None

    def _prepare(self) -> None:
        with self.transaction() as db:
            known = db.execute("SELECT to_regclass('meta') IS NOT NULL").fetchone()[0]
            if not known:
                tables = db.execute(
                    "SELECT COUNT(*) FROM information_schema.tables WHERE table_schema = 'public'"
                ).fetchone()[0]
                if tables:
                    raise InputError(self.url, "not a VGM Studio label store (no meta table)")
                for statement in TABLES.split(";"):
                    db.execute(statement)
                for key, value in (
                    ("format", FORMAT),
                    ("schema", str(SCHEMA)),
                    ("created_by", f"vgm-studio {__version__}"),
                    ("created_at", now()),
                ):
                    db.execute("INSERT INTO meta VALUES (?, ?)", (key, value))
            meta = dict(db.execute("SELECT key, value FROM meta").fetchall())
        if meta.get("format") != FORMAT:
            raise InputError(self.url, "not a VGM Studio label store (no format mark)")
        if meta.get("schema") != str(SCHEMA):
            raise InputError(
                self.url,
                f"store made by {meta.get('created_by', 'another version')} with schema "
                f"{meta.get('schema')}; this vgm-studio {__version__} reads schema {SCHEMA}",
            )

    def trainer_tables(self) -> None:
        """Made with the store: nothing to do."""

    def close(self) -> None:
        with self._opened_lock:
            for conn in self._opened:
                conn.close()
            self._opened.clear()

    def transaction(self) -> AbstractContextManager[_Connection]:
        """One committed transaction, writers serialised across servers; rolled back whole
        if anything inside raises."""
        return self._begin("BEGIN", lock=True)

    def snapshot(self) -> AbstractContextManager[_Connection]:
        """One consistent read-only view; takes no lock, so it never waits for a writer."""
        return self._begin("BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY", lock=False)

    @contextmanager
    def _begin(self, begin: str, lock: bool) -> Iterator[_Connection]:
        if self._depth:  # nested: part of the caller's transaction
            yield _Connection(self._conn)
            return
        self._reconnect_if_lost()
        # One round trip: BEGIN and the lock go together (no parameters, so both are sent as
        # one simple query).
        self._conn.execute(begin + (self._lock_sql() if lock else ""))
        self._depth += 1
        try:
            yield _Connection(self._conn)
        except BaseException:
            if not self._conn.broken:
                self._conn.execute("ROLLBACK")
            raise
        else:
            self._conn.execute("COMMIT")
        finally:
            self._depth -= 1

    def _lock_sql(self) -> str:
        """The writer's lock: the whole store, or (a label press) the store shared and one
        edge alone, so presses on different edges do not queue behind each other."""
        edge: str | None = getattr(self._local, "edge", None)
        if edge is None:
            return "; SELECT pg_advisory_xact_lock({}, {})".format(*_WRITE_LOCK)
        literal = psycopg.sql.Literal(edge).as_string(self._conn)
        return (
            "; SELECT pg_advisory_xact_lock_shared({}, {}), ".format(*_WRITE_LOCK)
            + f"pg_advisory_xact_lock({_EDGE_LOCKS}, hashtext({literal}))"
        )

    @contextmanager
    def for_edge(self, edge_id: str) -> Iterator[None]:
        """Within it, this thread's writes touch ``edge_id``'s labels and events only."""
        self._local.edge = edge_id
        try:
            yield
        finally:
            self._local.edge = None

    def _reconnect_if_lost(self) -> None:
        if not (self._conn.closed or self._conn.broken):
            return
        deadline = time.monotonic() + self.retry_seconds
        while True:
            try:
                self._conn = psycopg.connect(self.url, autocommit=True, connect_timeout=5)
                with self._opened_lock:
                    self.reconnects += 1
                return
            except psycopg.OperationalError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

    def query(self, sql: str, args: Iterable[Any] = ()) -> list[Any]:
        """The rows of one statement, outside any transaction of the caller's; retried once
        the server is back."""
        return self.retrying(lambda: self._query(sql, args))

    def _query(self, sql: str, args: Iterable[Any]) -> list[Any]:
        if not self._depth:
            self._reconnect_if_lost()
        return _Connection(self._conn).execute(sql, tuple(args)).fetchall()

    def retrying(self, call: Callable[[], T]) -> T:
        """``call()``, made again while the server is away (a restart), up to ``retry_seconds``.

        Only whole transactions are retried, and only when the connection broke: a statement
        the server refused is raised at once.
        """
        deadline = time.monotonic() + self.retry_seconds
        waited = False
        while True:
            try:
                result = call()
            except psycopg.OperationalError as exc:
                if self._depth or time.monotonic() > deadline:
                    raise
                if not waited:
                    self.report(f"label store unreachable ({_first_line(exc)}); retrying")
                    waited = True
                time.sleep(0.2)
            else:
                if waited:
                    self.report(None)
                return result

    def try_lock(self, key: tuple[int, int]) -> bool:
        """Takes a session advisory lock, held until this thread's connection closes."""
        row = self._conn.execute("SELECT pg_try_advisory_lock(%s, %s)", key).fetchone()
        return bool(row and row[0])

    def unlock(self, key: tuple[int, int]) -> None:
        """Lets go of a session advisory lock ``try_lock`` took."""
        self._conn.execute("SELECT pg_advisory_unlock(%s, %s)", key)


def _first_line(exc: Exception) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
