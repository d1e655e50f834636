"""The team label store: the same store on one PostgreSQL database that many servers share.

Why psycopg 3 and not SQLAlchemy 2: the store's SQL is hand-written once, in the subset of
SQL both SQLite and PostgreSQL speak (``store.py``, ``versions.py``, ``trainer_tables.py``),
and nothing above ``labels/`` sees a query. An ORM or SQLAlchemy Core would be a second query
layer for a dozen statements; psycopg 3 is the driver SQLAlchemy would use underneath anyway,
with server-side parameters, ``LISTEN``/``NOTIFY`` and advisory locks one call away. One
connection per process, shared by threads under a lock, mirrors the SQLite store; a pool
(``psycopg_pool``) would buy nothing since every transaction here is a few milliseconds long.

The guarantees are the SQLite store's:

* Every label, skip and undo is its own committed transaction (``synchronous_commit`` is the
  server's default, on), appended to ``events``; ``labels`` is derived in the same one.
* Writers are serialised per store by a transaction-scoped advisory lock, just as SQLite's
  ``BEGIN IMMEDIATE`` serialises them, so ``MAX(position) + 1`` and ``MAX(version) + 1`` stay
  race-free across servers; a label press (label, skip, import of one label) takes that lock
  shared and its edge's lock alone, so presses on different edges run side by side. Reads
  are ``REPEATABLE READ READ ONLY`` snapshots, never blocked.
* Claims: ``claim`` takes an edge for one annotator for a while (a row with an expiry, taken
  in one ``INSERT … ON CONFLICT`` statement), so no two annotators on any server are handed
  the same edge.
* One trainer per store: ``trainer_lock`` holds a session advisory lock, freed when the
  trainer's connection dies.
* The ``meta`` table carries the format and schema marks; another schema is refused in one line.
* A server restart: the connection is made again, and a label press in flight is retried for
  ``retry_seconds``; a label acknowledged before the restart was committed, so it stays.

The few SQLite spellings in the shared statements (``?``, ``INSERT OR IGNORE``, ``INSERT OR
REPLACE``, ``lastrowid``) are rewritten here, in one place, by ``_dialect``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import cast

from vgm_studio.errors import InputError
from vgm_studio.labels.database import Database

# Advisory lock keys (any two 32-bit numbers that are ours): writers, and the one trainer.
from vgm_studio.labels.pg_database import _TRAINER_LOCK, PgDatabase
from vgm_studio.labels.records import Event, LabelRecord
from vgm_studio.labels.store import LabelStore
from vgm_studio.labels.trainer_tables import TrainerTables
from vgm_studio.labels.versions import ModelVersions
from vgm_studio.matching.edges import Edge


class PgLabelStore(LabelStore):
    """The label store on a PostgreSQL server: ``LabelStore``'s interface and guarantees.

    Args:
        url: ``postgresql://USER@HOST[:PORT]/DB``; the tables are made in an empty database.
        models_dir: The folder for model checkpoints (``models/vN.pt`` under it); every host
            that runs a trainer or loads versions must see the same folder.
        retry_seconds: How long a label press waits for a restarting server.

    Raises:
        InputError: A bad URL, no server, or a database of another version or not ours.
    """

    def __init__(
        self, url: str, models_dir: str | Path | None = None, retry_seconds: float = 30.0
    ) -> None:
        self.url = url
        database = PgDatabase(url, retry_seconds)
        # Shared-statement classes are typed against the SQLite Database; PgDatabase offers
        # the same methods and a connection with the same DB-API subset.
        self._db = cast(Database, database)
        self._pg = database
        self.path = database.path
        name = url.rstrip("/").rsplit("/", 1)[-1] or "vgm"
        self.workspace = Path(models_dir) if models_dir else Path(f"{name}.models")
        self.versions = ModelVersions(self._db, self.workspace)
        self.trainer = TrainerTables(self._db)

    @property
    def reconnects(self) -> int:
        """How many times the connection was made again (a server restart, say)."""
        return self._pg.reconnects

    def label(self, edge_id: str, annotator: str, label: str, note: str = "") -> Event:
        with self._pg.for_edge(edge_id):
            return self._pg.retrying(
                lambda: LabelStore.label(self, edge_id, annotator, label, note)
            )

    def skip(self, edge_id: str, annotator: str) -> Event:
        with self._pg.for_edge(edge_id):
            return self._pg.retrying(lambda: LabelStore.skip(self, edge_id, annotator))

    def undo(self, event_id: int) -> Event:
        return self._pg.retrying(lambda: LabelStore.undo(self, event_id))

    def import_label(self, record: LabelRecord) -> bool:
        with self._pg.for_edge(record.edge_id):
            return self._pg.retrying(lambda: LabelStore.import_label(self, record))

    def import_all(self, edges: Iterable[Edge], records: Iterable[LabelRecord]) -> tuple[int, int]:
        # Materialised first: a retry after a lost connection runs the whole import again.
        rows, labels = list(edges), list(records)
        return self._pg.retrying(lambda: LabelStore.import_all(self, rows, labels))

    def claim(
        self, edge_id: str, holder: str, seconds: float = 300.0, unlabelled: bool = True
    ) -> bool:
        """Takes ``edge_id`` for ``holder`` for ``seconds``, unless someone else holds it.

        Args:
            edge_id: The edge to hand to ``holder``.
            holder: Who takes it (an annotator's name, or a tab's id).
            seconds: How long the claim lasts unless released or renewed.
            unlabelled: Refuse an edge someone labelled already (the unlabelled queue).

        Returns:
            Whether ``holder`` now holds it.
        """
        return self._pg.retrying(lambda: self._claim(edge_id, holder, seconds, unlabelled))

    def _claim(self, edge_id: str, holder: str, seconds: float, unlabelled: bool) -> bool:
        # One statement, no store-wide lock: the row lock of ON CONFLICT decides between two
        # servers claiming at once, and moving on costs a label press nothing.
        rows = self._db.query(
            "INSERT INTO claims AS c (edge_id, holder, until) "
            "SELECT ?, ?, ? WHERE NOT (? AND EXISTS (SELECT 1 FROM labels WHERE edge_id = ?)) "
            "ON CONFLICT (edge_id) DO UPDATE SET holder = EXCLUDED.holder, until = EXCLUDED.until "
            "WHERE c.holder = EXCLUDED.holder OR c.until < ? RETURNING holder",
            (edge_id, holder, time.time() + seconds, unlabelled, edge_id, time.time()),
        )
        if (
            rows
            and unlabelled
            and self._db.query("SELECT 1 FROM labels WHERE edge_id = ? LIMIT 1", (edge_id,))
        ):
            # Labelled by the holder we displaced as it moved on: the check above read a
            # snapshot from before that label; this statement's snapshot is newer.
            self._db.query(
                "DELETE FROM claims WHERE edge_id = ? AND holder = ? RETURNING edge_id",
                (edge_id, holder),
            )
            return False
        return bool(rows)

    def release(self, holder: str) -> None:
        """Gives back every edge ``holder`` holds."""
        self._db.query("DELETE FROM claims WHERE holder = ? RETURNING edge_id", (holder,))

    def on_connection(self, report: Callable[[str | None], None]) -> None:
        """Calls ``report(line)`` when the server is lost mid-press, ``report(None)`` when back."""
        self._pg.report = report

    def trainer_lock(self, wait_seconds: float = 3.0) -> None:
        """Makes this process the store's one trainer until it exits.

        Raises:
            InputError: Another trainer holds the store.
        """
        # The server frees a dead trainer's lock when it notices the disconnect, a moment
        # after the process died: a restarted trainer waits that moment out.
        deadline = time.monotonic() + wait_seconds
        while not self._pg.try_lock(_TRAINER_LOCK):
            if time.monotonic() > deadline:
                raise InputError(self.url, "another trainer is running on this label store")
            time.sleep(0.1)

    def trainer_running(self) -> bool:
        """Whether another process holds the trainer lock (taken and let go to find out)."""
        if self._pg.try_lock(_TRAINER_LOCK):
            self._pg.unlock(_TRAINER_LOCK)
            return False
        return True


def _implements(store: PgLabelStore) -> LabelStore:
    """Never called: mypy checks the team store is a ``LabelStore`` (so a repository)."""
    return store
