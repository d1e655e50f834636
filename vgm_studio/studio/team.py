"""The studio's side of a label store: claims that hold across servers, and a line in the
panel while a team store cannot be reached.

Several studio servers may serve one store: a team store (PostgreSQL) on many hosts, or a
workspace's SQLite store opened by a second ``vgm-studio label --port 8081``. An unlabelled
edge is therefore claimed in the database before it is handed to a tab, and no two tabs of
any server on the store are handed the same edge.
"""

from __future__ import annotations

import os
import socket
import uuid
from collections.abc import Callable

from vgm_studio.labels.repository import SharedStore
from vgm_studio.labels.store import LabelStore


class StoreLink:
    """Claims in the store, and connection news of a team store.

    Args:
        store: The studio's label store.
        on_status: Told a line when the store becomes unreachable, None when it is back.
    """

    def __init__(self, store: LabelStore, on_status: Callable[[str | None], None]) -> None:
        self._store = store
        self._shared = store if isinstance(store, SharedStore) else None
        # Unique across servers and their tabs: host, process, this server (a process may
        # run two, as tests do), then the tab's client id.
        self._holder = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}:"
        if self._shared is not None:
            self._shared.on_connection(on_status)

    def claim(self, edge_id: str, client_id: int) -> bool:
        """Claims ``edge_id`` for the tab; false when a tab of another server holds it."""
        holder = self._holder + str(client_id)
        if self._shared is not None:
            return self._shared.claim(edge_id, holder)
        return self._store.claims.claim(edge_id, holder)

    def release(self, client_id: int) -> None:
        """Gives back every claim the tab holds."""
        holder = self._holder + str(client_id)
        if self._shared is not None:
            self._shared.release(holder)
        else:
            self._store.claims.release(holder)
