"""One browser tab's state in the studio."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import viser

from vgm_studio.studio.panel import Panel
from vgm_studio.studio.queues import Queue
from vgm_studio.studio.scene import TabScene


@dataclass
class Tab:
    """One browser tab's state. ``lock`` keeps its key presses in order."""

    client: viser.ClientHandle
    panel: Panel
    queue: Queue
    order: list[str]
    scene: TabScene
    index: int = 0
    # (event id, edge id); a skip has no event to take back, only a place to return to.
    undo: list[tuple[int | None, str]] = field(default_factory=list)
    lock: threading.RLock = field(default_factory=threading.RLock)
    failed: str | None = None  # why the edge shown cannot be drawn; labels are refused then

    @property
    def edge_id(self) -> str | None:
        return self.order[self.index] if 0 <= self.index < len(self.order) else None
