"""The studio's side of a team label store: claims that hold across servers, and a line in
the panel while the store cannot be reached.

A workspace's SQLite store serves one studio, whose in-memory claims are enough; a shared
store (PostgreSQL) is written by several studio servers, so an unlabelled edge is claimed in
the database before it is handed to a tab.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable

from vgm_studio.labels.repository import SharedStore
from vgm_studio.labels.store import LabelStore


class StoreLink:
    """Claims and connection news of a shared store; does nothing for a workspace's store.

    Args:
        store: The studio's label store.
        on_status: Told a line when the store becomes unreachable, None when it is back.
    """

    def __init__(self, store: LabelStore, on_status: Callable[[str | None], None]) -> None:
        self._shared = store if isinstance(store, SharedStore) else None
        # Unique across servers and their tabs: host, process, then the tab's client id.
        self._holder = f"{socket.gethostname()}:{os.getpid()}:"
        if self._shared is not None:
            self._shared.on_connection(on_status)

    def claim(self, edge_id: str, client_id: int) -> bool:
        """Claims ``edge_id`` for the tab in a shared store (always true otherwise)."""
        if self._shared is None:
            return True
        return self._shared.claim(edge_id, self._holder + str(client_id))

    def release(self, client_id: int) -> None:
        """Gives back every claim the tab holds in a shared store."""
        if self._shared is not None:
            self._shared.release(self._holder + str(client_id))
