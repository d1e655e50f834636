"""Claims on unlabelled edges in a workspace's SQLite store, so they hold across servers.

Two studio servers may serve one workspace (a second ``vgm-studio label --port 8081``). Each
keeps its tabs' claims in memory, which the other cannot see; the claims table makes "no two
annotators are handed the same edge" hold between them too, as ``postgres.py`` does for a
team store. A claim lasts ``seconds`` unless renewed, so a killed server's claims lapse.
"""

from __future__ import annotations

import time

from vgm_studio.labels.database import Database

# Not in schema 1's tables: made when missing, in any workspace, as the trainer's tables are.
CLAIMS_TABLE = (
    "CREATE TABLE IF NOT EXISTS claims ("
    "edge_id TEXT PRIMARY KEY, holder TEXT NOT NULL, until REAL NOT NULL)"
)


class Claims:
    """Who holds which unlabelled edge, in the workspace's database.

    Args:
        db: The workspace's database.
    """

    def __init__(self, db: Database) -> None:
        self._db = db
        self._made = False

    def _table(self) -> None:
        if not self._made:
            with self._db.transaction() as db:
                db.execute(CLAIMS_TABLE)
            self._made = True

    def claim(
        self, edge_id: str, holder: str, seconds: float = 300.0, unlabelled: bool = True
    ) -> bool:
        """Takes ``edge_id`` for ``holder`` unless another holder's claim is still on.

        One IMMEDIATE transaction: SQLite lets one writer in at a time, so two servers
        claiming the same edge at once are decided in turn.

        Args:
            edge_id: The edge to hand to ``holder``.
            holder: Who takes it (unique across servers: host, process and tab).
            seconds: How long the claim lasts unless released or renewed.
            unlabelled: Refuse an edge someone labelled already.

        Returns:
            Whether ``holder`` now holds it.
        """
        self._table()
        moment = time.time()
        with self._db.transaction() as db:
            if (
                unlabelled
                and db.execute(
                    "SELECT 1 FROM labels WHERE edge_id = ? LIMIT 1", (edge_id,)
                ).fetchone()
            ):
                return False
            row = db.execute("SELECT holder, until FROM claims WHERE edge_id = ?", (edge_id,))
            held = row.fetchone()
            if held is not None and held[0] != holder and held[1] >= moment:
                return False
            db.execute(
                "INSERT OR REPLACE INTO claims (edge_id, holder, until) VALUES (?, ?, ?)",
                (edge_id, holder, moment + seconds),
            )
            return True

    def release(self, holder: str) -> None:
        """Gives back every edge ``holder`` holds."""
        self._table()
        with self._db.transaction() as db:
            db.execute("DELETE FROM claims WHERE holder = ?", (holder,))
