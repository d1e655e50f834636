"""The labeling studio: a viser server where each browser tab steps through edges and labels them.

Every label goes to the store (committed) before the tab moves on. Each tab keeps its own queue
and position; in the queues that hand out unlabelled edges, an edge shown in one tab is
claimed and not handed to another.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import viser

from vgm_studio.labels.agreement import agreement
from vgm_studio.labels.records import Predictions
from vgm_studio.labels.store import LabelStore
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.studio.config import StudioConfig, check_port_free, default_annotator
from vgm_studio.studio.decisions import decision_rows, run_header, run_of
from vgm_studio.studio.gate import Gate, guarded_serve, is_loopback, new_token
from vgm_studio.studio.links import first_link, opening, requested
from vgm_studio.studio.panel import (
    agreement_text,
    ask_training,
    build_panel,
    code,
    facts_text,
    layers_text,
    plain,
    position_text,
)
from vgm_studio.studio.queues import RUN_QUEUES, Queue, Snapshot, order
from vgm_studio.studio.scene import Layers, TabScene
from vgm_studio.studio.tab import Tab
from vgm_studio.studio.team import StoreLink
from vgm_studio.studio.view import ViewCache

# Where commands have always imported them from.
__all__ = ["Studio", "StudioConfig", "check_port_free", "default_annotator"]

PREFETCH = 3


class Studio:
    """Serves a workspace's edges for labeling.

    Args:
        store: The workspace's store.
        config: How to serve.
        scans: Where edges' logs are read from (shared with a caller that has them open).
        train_now: Called by the panel's "Train now"; None: no trainer runs beside it.

    Example:
        >>> studio = Studio(LabelStore("ws"), StudioConfig(port=8080)); studio.start()
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
        edges = store.edges()  # read once: a run's decisions and reference labels stay put
        self._edge_ids = [e.edge_id for e in edges]
        self._edges: dict[str, Edge] = {e.edge_id: e for e in edges}
        self._run = run_of(edges)
        self.queues = [q for q in Queue if self._run.kept or q not in RUN_QUEUES]
        self._predictions = store.predictions()
        self._scoring: tuple[int, int] | None = None  # (done, total) while a model scores
        self._tabs: dict[int, Tab] = {}
        self._claims: dict[str, int] = {}
        self._lock = threading.RLock()
        self._prefetcher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="prefetch")
        self.server: viser.ViserServer | None = None
        # "Train now" in the panel; None when no trainer runs beside the studio.
        self._train_now_callback = train_now
        self._trainer_text = ""
        self._store_text: str | None = None
        self._link = StoreLink(store, self.show_store_status)

    @property
    def url(self) -> str:
        return Gate(self.config.host, self.config.token).url(self.config.port)

    def first_link(self) -> str | None:
        """A link to the first edge of the most telling queue (``links.first_link``)."""
        return first_link(self.url, self._snapshot(), self.queues)

    def start(self) -> viser.ViserServer:
        """Starts serving; returns at once (the server runs in its own threads).

        Off loopback the studio is reachable from other machines, so it then always asks for
        a token (made up here unless the config names one); ``url`` carries it.
        """
        check_port_free(self.config.host, self.config.port)
        if self.config.token is None and not is_loopback(self.config.host):
            self.config.token = new_token()
        with guarded_serve(Gate(self.config.host, self.config.token)):
            server = viser.ViserServer(host=self.config.host, port=self.config.port, verbose=False)
        server.gui.configure_theme(titlebar_content=None, control_width="large", dark_mode=True)
        # Docked, not floating: the 3D view ends where the panel begins, so a framed pair is
        # never hidden under it.
        server.gui.main_panel.dock_right()
        server.scene.set_up_direction("+z")
        server.scene.world_axes.visible = False
        # A flat top-down view needs no shadows, and shadow passes cost the most where the
        # browser renders without a GPU.
        server.scene.configure_default_lights(True, cast_shadow=False)
        # No server-wide initial camera: the browser would reset to it after the tab's own
        # framing of its first edge had arrived. Each tab frames its edges (scene.TabScene).
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

    def show_scores(self, scores: Predictions, progress: tuple[int, int] | None) -> None:
        """Shows p(success) while a model scores the edges (``scoring.Scorer``), in every tab."""
        self._predictions, self._scoring = scores, progress
        for tab in list(self._tabs.values()):
            with tab.lock:
                self._show(tab, draw_scene=False)

    def upcoming(self) -> list[str]:
        """The edges the tabs show and show next, which a model scores first."""
        tabs = list(self._tabs.values())
        return [e for t in tabs for e in t.order[max(t.index, 0) : t.index + 1 + PREFETCH]]

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
        text = f"**{plain(line)}**; labels already acknowledged are stored" if line else None
        for tab in list(self._tabs.values()):
            tab.panel.trainer.content = text or self._trainer_text

    # -- tabs ----------------------------------------------------------------------------

    def _snapshot(self, labels: dict[str, dict[str, str]] | None = None) -> Snapshot:
        p, labels = self._predictions, self.store.label_map() if labels is None else labels
        return Snapshot(self._edge_ids, labels, p.p, p.threshold, self._run)

    def _tab_actions(self, tab: Tab) -> dict[str, Callable[[], None]]:
        return {
            "success": lambda: self._label(tab, "success"),
            "failure": lambda: self._label(tab, "failure"),
            "skip": lambda: self._skip(tab),
            "undo": lambda: self._undo(tab),
            "previous": lambda: self._step(tab, -1),
            "next": lambda: self._step(tab, +1),
            "guess": lambda: self._toggle_guess(tab),
            "layers": lambda: self._cycle_layers(tab),
            "reset_view": lambda: tab.scene.reset_view(),
            "train_now": lambda: ask_training(tab.client, self._train_now_callback),
        }

    def _connect(self, client: viser.ClientHandle) -> None:
        actions: dict[str, Callable[[], None]] = {}
        start = opening(requested(self.server, client.client_id), self.config.queue,
                        self._snapshot(), self.queues)  # fmt: skip
        panel = build_panel(client, self.config.annotator, start.queue, actions, self.queues)
        panel.trainer.content = self._trainer_text
        panel.layers.content = layers_text(Layers.both.value)
        tab = Tab(client, panel, start.queue, start.order, TabScene(client))
        actions.update(self._tab_actions(tab))
        panel.queue.on_update(lambda _e: self._switch_queue(tab, Queue(panel.queue.value)))
        panel.show_guess.on_update(lambda _e: self._redraw(tab))
        client.camera.on_update(lambda _camera: self._lens_changed(tab))
        with tab.lock:
            self._tabs[client.client_id] = tab
            tab.index = -1 if start.index is None else start.index
            self._move(tab, +1 if start.index is None else 0)
        if start.note:
            client.add_notification("Link", start.note, auto_close_seconds=6.0)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self._tabs.pop(client.client_id, None)
            for edge_id in [e for e, c in self._claims.items() if c == client.client_id]:
                del self._claims[edge_id]
        self._link.release(client.client_id)

    def _edge(self, edge_id: str) -> Edge:
        edge = self._edges.get(edge_id)
        if edge is None:
            edge = self._edges[edge_id] = self.store.edge(edge_id)
        return edge

    # -- actions -------------------------------------------------------------------------

    def _label(self, tab: Tab, label: str) -> None:
        with tab.lock:
            edge_id = tab.edge_id
            if edge_id is None:
                return
            if tab.failed is not None:
                # Nobody saw this edge: a label for it would be a guess.
                tab.client.add_notification(
                    "Not labelled", "This edge cannot be shown.", auto_close_seconds=3.0
                )
                return
            annotator = tab.panel.annotator.value.strip() or self.config.annotator
            event = self.store.label(edge_id, annotator, label, tab.panel.note.value.strip())
            tab.undo.append((event.id, edge_id))
            tab.panel.note.value = ""  # type: ignore[misc]  # viser's setter, unseen by mypy
            self._move(tab, +1)

    def _skip(self, tab: Tab) -> None:
        with tab.lock:
            if tab.edge_id is not None:
                annotator = tab.panel.annotator.value.strip() or self.config.annotator
                self.store.skip(tab.edge_id, annotator)
                tab.undo.append((None, tab.edge_id))
            self._move(tab, +1)

    def _undo(self, tab: Tab) -> None:
        with tab.lock:
            if not tab.undo:
                tab.client.add_notification("Nothing to undo", "", auto_close_seconds=2.0)
                return
            event_id, edge_id = tab.undo.pop()
            try:
                if event_id is not None:  # a skip changed no label: going back undoes it
                    self.store.undo(event_id)
            except ValueError as exc:
                tab.client.add_notification("Cannot undo", str(exc), auto_close_seconds=4.0)
                return
            if edge_id not in tab.order:
                tab.order.insert(max(tab.index, 0), edge_id)
            tab.index = tab.order.index(edge_id)
            self._claim(tab, edge_id)
            self._show(tab)

    def _step(self, tab: Tab, step: int) -> None:
        with tab.lock:
            self._move(tab, step)

    def _toggle_guess(self, tab: Tab) -> None:
        # Setting the checkbox fires its on_update, which redraws.
        tab.panel.show_guess.value = not tab.panel.show_guess.value  # type: ignore[misc]

    def _redraw(self, tab: Tab) -> None:
        with tab.lock:
            self._show(tab)

    def _lens_changed(self, tab: Tab) -> None:
        with tab.lock:
            tab.scene.lens_changed()

    def _cycle_layers(self, tab: Tab) -> None:
        with tab.lock:
            layers = tab.scene.cycle_layers()
            tab.panel.layers.content = layers_text(layers.value)

    def _switch_queue(self, tab: Tab, queue: Queue) -> None:
        with tab.lock:
            if queue is tab.queue:
                return
            tab.queue = queue
            tab.order = order(queue, self._snapshot())
            tab.index = -1
            self._move(tab, +1)

    # -- moving and showing --------------------------------------------------------------

    def _claim(self, tab: Tab, edge_id: str | None) -> None:
        with self._lock:
            for e in [e for e, c in self._claims.items() if c == tab.client.client_id]:
                del self._claims[e]
            if edge_id is not None:
                self._claims[edge_id] = tab.client.client_id

    def _move(self, tab: Tab, step: int) -> None:
        """Moves ``step`` along the queue; unlabelled queues go to the next free unlabelled edge."""
        if tab.queue.hands_out_unlabelled and step > 0:
            labels = self.store.label_map()
            with self._lock:
                n = len(tab.order)
                start = tab.index + 1
                candidates = [(start + k) % n for k in range(n)] if n else []
                self._link.release(tab.client.client_id)
                for i in candidates:
                    e = tab.order[i]
                    held = self._claims.get(e)
                    free = not labels.get(e) and held in (None, tab.client.client_id)
                    if free and self._link.claim(e, tab.client.client_id):
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

    def _show(self, tab: Tab, draw_scene: bool = True) -> None:
        edge_id = tab.edge_id
        labels = self.store.label_map()
        labelled = sum(1 for e in self._edge_ids if labels.get(e))
        panel = tab.panel
        with tab.client.atomic():
            if tab.queue is Queue.conflicts:
                panel.agreement.content = agreement_text(agreement(labels))
            if panel.agreement.visible != (tab.queue is Queue.conflicts):
                panel.agreement.visible = tab.queue is Queue.conflicts
            if edge_id is None:
                tab.failed = None
                panel.facts.content = "**This queue is empty.** Choose another queue below."
                tab.scene.clear()
            else:
                self._show_edge(tab, edge_id, labels.get(edge_id, {}), draw_scene)
            panel.progress.value = 100.0 * labelled / max(len(self._edge_ids), 1)
            # Last: the position line changing tells a watcher that the whole edge is there.
            total = len(self._edge_ids)
            where = position_text(max(tab.index, 0), len(tab.order), labelled, total, tab.queue)
            mark = f"  \n{code(edge_id)}" if edge_id else ""
            panel.position.content = where + run_header(self._snapshot(labels)) + mark
        self._prefetch(tab)

    def _show_edge(self, tab: Tab, edge_id: str, votes: dict[str, str], draw_scene: bool) -> None:
        """The edge's facts, and (``draw_scene``) its scene and pictures, or why it cannot be."""
        panel = tab.panel
        edge = self._edge(edge_id)
        use_guess = bool(panel.show_guess.value)
        if draw_scene or tab.failed is not None:
            view, tab.failed = self._views.get_or_reason(edge)
            if view is None:
                tab.scene.clear()
            else:
                placed = view.guess if use_guess else view.estimate
                tab.scene.show(view, placed)
                panel.vgm.image = placed.channels_rgb
                if view.minimap is not None:
                    panel.minimap.image = view.minimap
                if panel.minimap.visible != (view.minimap is not None):
                    panel.minimap.visible = view.minimap is not None
        notes = {r.annotator: r.note for r in self.store.labels(edge_id)} if votes else None
        facts = facts_text(
            edge,
            votes,
            self._predictions.p.get(edge_id),
            self._predictions.threshold,
            use_guess,
            notes,
            self._scoring,
            decision_rows(edge),
        )
        if tab.failed is not None:
            facts = (
                f"**This edge cannot be shown:** {plain(tab.failed)}  \n"
                "Labels are refused for it; fix the log or press E for the next edge.\n\n" + facts
            )
        panel.facts.content = facts

    def _prefetch(self, tab: Tab) -> None:
        upcoming = tab.order[tab.index + 1 : tab.index + 1 + PREFETCH]
        for edge_id in upcoming:
            self._prefetcher.submit(self._views.get, self._edge(edge_id))
