"""The trainer's share of the workspace: its reported state, training requests, the sticky
held-out split, and what it has not read yet."""

from __future__ import annotations

import json
import socket
import sqlite3
from collections.abc import Callable

from vgm_studio.labels.database import Database, now
from vgm_studio.labels.records import TrainerView
from vgm_studio.labels.versions import active_in, finish_requests, write_state

# Given the split known so far (edge_id → 1 held out, 0 trained on), the new edges to add.
SplitDealer = Callable[[dict[str, int]], list[tuple[str, int]]]


def _labels_since(db: sqlite3.Connection, seen: int) -> int:
    row = db.execute(
        "SELECT COUNT(*) FROM events e WHERE e.id > ? AND e.action IN ('label', 'import') "
        "AND NOT EXISTS (SELECT 1 FROM events u WHERE u.undoes = e.id)",
        (seen,),
    ).fetchone()
    return int(row[0])


class TrainerTables:
    """The trainer's tables in one workspace (made when missing).

    Args:
        database: The workspace's database.
    """

    def __init__(self, database: Database) -> None:
        self._db = database

    def report(self, values: dict[str, str], with_host: bool = False) -> None:
        """Writes state keys in one small committed transaction (``updated_at`` besides)."""
        self._db.trainer_tables()
        if with_host:
            values = {**values, "host": socket.gethostname()}
        with self._db.transaction() as db:
            write_state(db, values)

    def state(self) -> dict[str, str]:
        """The trainer's last report."""
        self._db.trainer_tables()
        with self._db.snapshot() as db:
            return dict(db.execute("SELECT key, value FROM trainer_state").fetchall())

    def request(self, from_scratch: bool = False) -> int:
        """Asks the trainer to train now; returns the request's id."""
        self._db.trainer_tables()
        with self._db.transaction() as db:
            cur = db.execute(
                "INSERT INTO train_requests (requested_at, from_scratch) VALUES (?, ?)",
                (now(), int(from_scratch)),
            )
        assert cur.lastrowid is not None
        return int(cur.lastrowid)

    def pending(self) -> list[tuple[int, bool]]:
        """(id, from_scratch) of requests not yet served, oldest first."""
        self._db.trainer_tables()
        with self._db.snapshot() as db:
            rows = db.execute(
                "SELECT id, from_scratch FROM train_requests WHERE done_at IS NULL ORDER BY id"
            ).fetchall()
        return [(int(i), bool(s)) for i, s in rows]

    def finish(self, up_to: int) -> None:
        """Marks requests up to id ``up_to`` served."""
        self._db.trainer_tables()
        with self._db.transaction() as db:
            finish_requests(db, up_to)

    def progress(self, seen: int) -> tuple[int, int]:
        """(labels made after event ``seen`` and not undone, the newest event's id), read at
        one moment."""
        with self._db.snapshot() as db:
            newest = db.execute("SELECT COALESCE(MAX(id), 0) FROM events").fetchone()[0]
            return _labels_since(db, seen), int(newest)

    def deal_split(self, dealer: SplitDealer) -> dict[str, int]:
        """Extends the held-out split in one transaction: ``dealer`` sees the split known so
        far and names the new edges; returns the whole split."""
        self._db.trainer_tables()
        with self._db.transaction() as db:
            known = dict(db.execute("SELECT edge_id, held_out FROM trainer_split").fetchall())
            new = dealer(dict(known))
            db.executemany("INSERT INTO trainer_split VALUES (?, ?)", new)
        known.update(new)
        return known

    def view(self) -> TrainerView:
        """Everything the status line shows, read at one moment; cheap enough to poll."""
        self._db.trainer_tables()
        with self._db.snapshot() as db:
            state = dict(db.execute("SELECT key, value FROM trainer_state").fetchall())
            active = active_in(db)
            metrics = db.execute("SELECT metrics FROM models WHERE version = ?", (active,))
            metrics_row = metrics.fetchone()
            since = _labels_since(db, int(state.get("events_seen", "0")))
            pending = db.execute(
                "SELECT 1 FROM train_requests WHERE done_at IS NULL LIMIT 1"
            ).fetchone()
            shown = db.execute("SELECT value FROM meta WHERE key = 'active_model'").fetchone()
        return TrainerView(
            state=state,
            active_version=active,
            active_metrics=json.loads(metrics_row[0]) if metrics_row else {},
            active_model=shown[0] if shown else None,
            labels_since=since,
            pending_request=pending is not None,
        )
