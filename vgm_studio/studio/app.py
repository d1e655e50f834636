"""The labeling studio: a viser server where each browser tab steps through edges and labels them.

Every label goes to the store (committed) before the tab moves on. Each tab keeps its own queue
and position; in the queues that hand out unlabelled edges, an edge shown in one tab is
claimed and not handed to another.
"""

from __future__ import annotations

import getpass
import os
import socket
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import viser

from vgm_studio.errors import InputError
from vgm_studio.labels.repository import SharedStore
from vgm_studio.labels.store import LabelStore
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.studio.panel import Panel, build_panel, facts_text, position_text
from vgm_studio.studio.queues import Queue, Snapshot, order
from vgm_studio.studio.view import (
    CUR_RGB,
    PREV_RGB,
    REFERENCE_RGB,
    EdgeView,
    ViewCache,
    pose_marks,
)
from vgm_studio.vgm.grid import VGMParams

_ONE_POINT = np.zeros((1, 3), dtype=np.float32)  # placeholder until an edge has a reference
PREFETCH = 3


def default_annotator() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return "annotator"


@dataclass
class StudioConfig:
    """How the studio serves.

    Attributes:
        host: Interface to listen on; 127.0.0.1 keeps it on this machine.
        port: TCP port.
        annotator: Name a new tab starts with.
        queue: Queue a new tab starts in.
        vgm: Grid the heatmap is drawn on.
        title: Shown in the browser's title bar.
    """

    host: str = "127.0.0.1"
    port: int = 8080
    annotator: str = field(default_factory=default_annotator)
    queue: Queue = Queue.unlabelled
    vgm: VGMParams = field(default_factory=VGMParams)
    title: str = "VGM Studio"


@dataclass
class _Tab:
    """One browser tab's state. ``lock`` keeps its key presses in order."""

    client: viser.ClientHandle
    panel: Panel
    queue: Queue
    order: list[str]
    index: int = 0
    undo: list[tuple[int, str]] = field(default_factory=list)  # (event id, edge id)
    lock: threading.RLock = field(default_factory=threading.RLock)
    nodes: dict[str, Any] = field(default_factory=dict)  # scene nodes, made once per tab

    @property
    def edge_id(self) -> str | None:
        return self.order[self.index] if 0 <= self.index < len(self.order) else None


def check_port_free(host: str, port: int) -> None:
    """Fails before the server starts when another program holds the port.

    Raises:
        InputError: The port is in use or the host is not an address of this machine.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            reason = "is in use; pass another --port" if exc.errno == 98 else f"({exc.strerror})"
            raise InputError(f"{host}:{port}", f"cannot listen: the port {reason}") from None


class Studio:
    """Serves a workspace's edges for labeling.

    Args:
        store: The workspace's store.
        config: How to serve.
        scans: Where edges' logs are read from (shared with a caller that has them open).
        train_now: Called by the panel's "Train now"; None: no trainer runs beside it.

    Example:
        >>> studio = Studio(LabelStore("ws"), StudioConfig(port=8080))
        >>> studio.start()
        >>> print(studio.url)
    """

    def __init__(
        self,
        store: LabelStore,
        config: StudioConfig,
        scans: EdgeScans | None = None,
        train_now: Callable[[], None] | None = None,
    ) -> None:
        self.store = store
        self.config = config
        self._views = ViewCache(scans or EdgeScans(), config.vgm)
        self._edge_ids = store.edge_ids()
        self._edges: dict[str, Edge] = {}
        self._predictions = store.predictions()
        self._tabs: dict[int, _Tab] = {}
        self._claims: dict[str, int] = {}
        self._lock = threading.RLock()
        self._prefetcher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="prefetch")
        self.server: viser.ViserServer | None = None
        # "Train now" in the panel; None when no trainer runs beside the studio.
        self._train_now_callback = train_now
        self._trainer_text = ""
        self._store_text: str | None = None
        # A team store: claims hold across servers, and a lost connection is said in the panel.
        self._shared = store if isinstance(store, SharedStore) else None
        self._holder = f"{socket.gethostname()}:{os.getpid()}:"
        if self._shared is not None:
            self._shared.on_connection(self.show_store_status)

    @property
    def url(self) -> str:
        host = "localhost" if self.config.host in ("127.0.0.1", "0.0.0.0") else self.config.host
        return f"http://{host}:{self.config.port}"

    def start(self) -> viser.ViserServer:
        """Starts serving; returns at once (the server runs in its own threads)."""
        check_port_free(self.config.host, self.config.port)
        server = viser.ViserServer(host=self.config.host, port=self.config.port, verbose=False)
        server.gui.configure_theme(
            titlebar_content=None, control_layout="fixed", control_width="large", dark_mode=True
        )
        server.scene.set_up_direction("+z")
        server.scene.world_axes.visible = False
        # A flat top-down view needs no shadows, and shadow passes cost the most where the
        # browser renders without a GPU.
        server.scene.configure_default_lights(True, cast_shadow=False)
        # Straight down on the previous scan's origin, +x right and +y up, ±7 m in view;
        # "Reset View" in the browser comes back here.
        server.initial_camera.position = (0.0, -0.001, 11.0)
        server.initial_camera.look_at = (0.0, 0.0, 0.0)
        server.initial_camera.up = (0.0, 0.0, 1.0)
        server.on_client_connect(self._connect)
        server.on_client_disconnect(self._disconnect)
        self.server = server
        return server

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
        self._prefetcher.shutdown(wait=False, cancel_futures=True)

    # -- predictions ---------------------------------------------------------------------

    def refresh_predictions(self) -> None:
        """Rereads the active model's predictions and shows them in every tab.

        Tabs in a queue ordered by the model are reordered; the edge a tab shows stays in
        front, so nobody is yanked away from the edge they are looking at.
        """
        self._predictions = self.store.predictions()
        snap = self._snapshot()
        for tab in list(self._tabs.values()):
            with tab.lock:
                if tab.queue in (Queue.uncertain, Queue.disagree):
                    current = tab.edge_id
                    fresh = order(tab.queue, snap)
                    if current is not None:
                        fresh = [current, *(e for e in fresh if e != current)]
                    tab.order, tab.index = fresh, 0
                self._show(tab, draw_scene=False)

    def show_trainer(self, text: str) -> None:
        """Shows the background trainer's state in every tab (called from the watcher)."""
        if text == self._trainer_text:
            return
        self._trainer_text = text
        if self._store_text:  # a lost label store is the more urgent line
            return
        for tab in list(self._tabs.values()):
            tab.panel.trainer.content = text

    def show_store_status(self, line: str | None) -> None:
        """Says in every tab that the label store is unreachable (None: it is back)."""
        self._store_text = line
        text = f"**{line}**; labels already acknowledged are stored" if line else None
        for tab in list(self._tabs.values()):
            tab.panel.trainer.content = text or self._trainer_text

    def _held_in_store(self, edge_id: str, tab: _Tab) -> bool:
        """Claims ``edge_id`` for the tab in a shared store (always true for a workspace's)."""
        if self._shared is None:
            return True
        return self._shared.claim(edge_id, self._holder + str(tab.client.client_id))

    def _train_now(self, tab: _Tab) -> None:
        if self._train_now_callback is None:
            tab.client.add_notification(
                "No trainer", "This studio runs without one.", auto_close_seconds=3.0
            )
            return
        self._train_now_callback()
        tab.client.add_notification(
            "Training asked for", "The trainer starts a new version.", auto_close_seconds=3.0
        )

    # -- tabs ----------------------------------------------------------------------------

    def _snapshot(self) -> Snapshot:
        preds = self._predictions
        return Snapshot(self._edge_ids, self.store.label_map(), preds.p, preds.threshold)

    def _tab_actions(self, tab: _Tab) -> dict[str, Callable[[], None]]:
        return {
            "success": lambda: self._label(tab, "success"),
            "failure": lambda: self._label(tab, "failure"),
            "skip": lambda: self._skip(tab),
            "undo": lambda: self._undo(tab),
            "previous": lambda: self._step(tab, -1),
            "next": lambda: self._step(tab, +1),
            "guess": lambda: self._toggle_guess(tab),
            "train_now": lambda: self._train_now(tab),
        }

    def _connect(self, client: viser.ClientHandle) -> None:
        actions: dict[str, Callable[[], None]] = {}
        panel = build_panel(client, self.config.annotator, self.config.queue, actions)
        panel.trainer.content = self._trainer_text
        tab = _Tab(client, panel, self.config.queue, order(self.config.queue, self._snapshot()))
        actions.update(self._tab_actions(tab))
        panel.queue.on_update(lambda _e: self._switch_queue(tab, Queue(panel.queue.value)))
        panel.show_guess.on_update(lambda _e: self._redraw(tab))
        with tab.lock:
            self._tabs[client.client_id] = tab
            tab.index = -1
            self._move(tab, +1)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self._tabs.pop(client.client_id, None)
            for edge_id in [e for e, c in self._claims.items() if c == client.client_id]:
                del self._claims[edge_id]
        if self._shared is not None:
            self._shared.release(self._holder + str(client.client_id))

    def _edge(self, edge_id: str) -> Edge:
        edge = self._edges.get(edge_id)
        if edge is None:
            edge = self._edges[edge_id] = self.store.edge(edge_id)
        return edge

    # -- actions -------------------------------------------------------------------------

    def _label(self, tab: _Tab, label: str) -> None:
        with tab.lock:
            edge_id = tab.edge_id
            if edge_id is None:
                return
            annotator = tab.panel.annotator.value.strip() or self.config.annotator
            event = self.store.label(edge_id, annotator, label, tab.panel.note.value.strip())
            tab.undo.append((event.id, edge_id))
            tab.panel.note.value = ""  # type: ignore[misc]  # viser's setter, unseen by mypy
            self._move(tab, +1)

    def _skip(self, tab: _Tab) -> None:
        with tab.lock:
            if tab.edge_id is not None:
                annotator = tab.panel.annotator.value.strip() or self.config.annotator
                self.store.skip(tab.edge_id, annotator)
            self._move(tab, +1)

    def _undo(self, tab: _Tab) -> None:
        with tab.lock:
            if not tab.undo:
                tab.client.add_notification("Nothing to undo", "", auto_close_seconds=2.0)
                return
            event_id, edge_id = tab.undo.pop()
            try:
                self.store.undo(event_id)
            except ValueError as exc:
                tab.client.add_notification("Cannot undo", str(exc), auto_close_seconds=4.0)
                return
            if edge_id not in tab.order:
                tab.order.insert(max(tab.index, 0), edge_id)
            tab.index = tab.order.index(edge_id)
            self._claim(tab, edge_id)
            self._show(tab)

    def _step(self, tab: _Tab, step: int) -> None:
        with tab.lock:
            self._move(tab, step)

    def _toggle_guess(self, tab: _Tab) -> None:
        # Setting the checkbox fires its on_update, which redraws.
        tab.panel.show_guess.value = not tab.panel.show_guess.value  # type: ignore[misc]

    def _redraw(self, tab: _Tab) -> None:
        with tab.lock:
            self._show(tab)

    def _switch_queue(self, tab: _Tab, queue: Queue) -> None:
        with tab.lock:
            if queue is tab.queue:
                return
            tab.queue = queue
            tab.order = order(queue, self._snapshot())
            tab.index = -1
            self._move(tab, +1)

    # -- moving and showing --------------------------------------------------------------

    def _claim(self, tab: _Tab, edge_id: str | None) -> None:
        with self._lock:
            for e in [e for e, c in self._claims.items() if c == tab.client.client_id]:
                del self._claims[e]
            if edge_id is not None:
                self._claims[edge_id] = tab.client.client_id

    def _move(self, tab: _Tab, step: int) -> None:
        """Moves ``step`` along the queue; unlabelled queues go to the next free unlabelled edge."""
        if tab.queue.hands_out_unlabelled and step > 0:
            labels = self.store.label_map()
            with self._lock:
                n = len(tab.order)
                start = tab.index + 1
                candidates = [(start + k) % n for k in range(n)] if n else []
                if self._shared is not None:
                    self._shared.release(self._holder + str(tab.client.client_id))
                for i in candidates:
                    e = tab.order[i]
                    held = self._claims.get(e)
                    free = not labels.get(e) and held in (None, tab.client.client_id)
                    if free and self._held_in_store(e, tab):
                        tab.index = i
                        break
                else:
                    tab.index = min(max(tab.index + 1, 0), n - 1) if n else 0
                self._claim(tab, tab.edge_id)
        else:
            if tab.order:
                tab.index = min(max(tab.index + step, 0), len(tab.order) - 1)
            self._claim(tab, tab.edge_id)
        self._show(tab)

    def _show(self, tab: _Tab, draw_scene: bool = True) -> None:
        edge_id = tab.edge_id
        labels = self.store.label_map()
        labelled = sum(1 for e in self._edge_ids if labels.get(e))
        panel = tab.panel
        with tab.client.atomic():
            if edge_id is None:
                panel.facts.content = "**This queue is empty.** Choose another queue below."
                self._clear_scene(tab)
            else:
                edge = self._edge(edge_id)
                use_guess = bool(panel.show_guess.value)
                if draw_scene:
                    self._draw(tab, self._views.get(edge), use_guess)
                panel.facts.content = facts_text(
                    edge,
                    labels.get(edge_id, {}),
                    self._predictions.p.get(edge_id),
                    self._predictions.threshold,
                    use_guess,
                )
            panel.progress.value = 100.0 * labelled / max(len(self._edge_ids), 1)
            # Last: the position line changing tells a watcher that the whole edge is there.
            panel.position.content = position_text(
                max(tab.index, 0), len(tab.order), labelled, len(self._edge_ids), tab.queue
            ) + (f"  \n`{edge_id}`" if edge_id else "")
        self._prefetch(tab)

    def _prefetch(self, tab: _Tab) -> None:
        upcoming = tab.order[tab.index + 1 : tab.index + 1 + PREFETCH]
        for edge_id in upcoming:
            self._prefetcher.submit(self._views.get, self._edge(edge_id))

    def _draw(self, tab: _Tab, view: EdgeView, use_guess: bool) -> None:
        """Puts the edge into the tab's scene, updating the nodes made for earlier edges.

        Updating a node's data is much cheaper for the browser than removing and adding it
        again: on a machine without a GPU that was most of a click's latency.
        """
        placed = view.guess if use_guess else view.estimate
        nodes = tab.nodes
        if not nodes:
            scene = tab.client.scene
            nodes["vgm"] = scene.add_image(
                "/vgm",
                placed.heatmap_rgb,
                render_width=placed.heatmap_size[0],
                render_height=placed.heatmap_size[1],
                format="png",
                cast_shadow=False,
                receive_shadow=False,
                position=(*placed.heatmap_centre, -0.01),
            )
            nodes["previous"] = scene.add_point_cloud(
                "/scans/previous", view.prev, PREV_RGB, point_size=0.025
            )
            nodes["current"] = scene.add_point_cloud(
                "/scans/current", placed.cur, CUR_RGB, point_size=0.025
            )
            nodes["reference_scan"] = scene.add_point_cloud(
                "/reference/scan", _ONE_POINT, REFERENCE_RGB, point_size=0.02
            )
            segments, colours = pose_marks(placed.pose, view.reference)
            nodes["poses"] = scene.add_line_segments(
                "/poses", segments, colours, thickness=4.0, thickness_units="screen"
            )
        else:
            image = nodes["vgm"]
            image.image = placed.heatmap_rgb
            image.render_width, image.render_height = placed.heatmap_size
            image.position = (*placed.heatmap_centre, -0.01)
            nodes["previous"].points = view.prev
            nodes["current"].points = placed.cur
            nodes["poses"].points, nodes["poses"].colors = pose_marks(placed.pose, view.reference)
        for name in ("vgm", "previous", "current", "poses"):
            if not nodes[name].visible:
                nodes[name].visible = True
        has_reference = view.reference is not None
        if nodes["reference_scan"].visible != has_reference:
            nodes["reference_scan"].visible = has_reference
        if view.reference is not None:
            nodes["reference_scan"].points = view.reference[1]

    def _clear_scene(self, tab: _Tab) -> None:
        for node in tab.nodes.values():
            node.visible = False
