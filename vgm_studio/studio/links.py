"""Links to one edge: ``http://HOST:PORT/?edge=EDGE_ID&queue=kept-failure`` opens that edge.

viser's page connects its websocket from a web worker, to the page's address without its
query, so the server never sees ``?edge=``. ``LINK_JS`` (added to the page by ``gate``) hands
the page's ``edge`` and ``queue`` parameters on: it appends them to the address the page gives
its worker (viser's ``set_server`` message), so they arrive with the websocket's request,
which the studio reads when the tab connects (``requested``). viser 1.1 has no public word
for a client's address; it keeps each client's websockets connection, and that connection
keeps its request.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, quote, urlsplit

from vgm_studio.studio.queues import Queue, Snapshot, order

# Runs before viser's own script: the worker it makes is then ours.
LINK_JS = """<script>
(() => {
  const page = new URLSearchParams(window.location.search);
  const wanted = new URLSearchParams();
  for (const key of ["edge", "queue"]) {
    if (page.get(key)) wanted.set(key, page.get(key));
  }
  if (![...wanted.keys()].length || typeof window.Worker !== "function") return;
  const Base = window.Worker;
  window.Worker = class extends Base {
    postMessage(message, ...rest) {
      if (message && message.type === "set_server" && typeof message.server === "string") {
        const url = new URL(message.server);
        for (const [key, value] of wanted) url.searchParams.set(key, value);
        message = { ...message, server: url.toString() };
      }
      return super.postMessage(message, ...rest);
    }
  };
})();
</script>"""


@dataclass(frozen=True)
class Link:
    """What a tab's address asks for: an edge, and the queue to show it in."""

    edge_id: str | None = None
    queue: Queue | None = None
    unknown_queue: str | None = None  # a ``queue=`` that names no queue


def parse(path: str) -> Link:
    """The link in a request path (``/TOKEN?edge=…&queue=…``)."""
    query = parse_qs(urlsplit(path).query)
    edge = query.get("edge", [""])[0]
    name = query.get("queue", [""])[0]
    queue = next((q for q in Queue if name in (q.slug, q.name, q.value)), None) if name else None
    return Link(edge or None, queue, name if name and queue is None else None)


def requested(server: Any, client_id: int) -> Link:
    """The link a tab was opened by: its websocket request's path, read from the viser
    server's live connections (an empty link where viser keeps none)."""
    live = getattr(getattr(server, "_websock_server", None), "_live_connections", {})
    request = getattr(live.get(client_id), "request", None)
    path = getattr(request, "path", None)
    return parse(path if isinstance(path, str) else "/")


def link_url(base: str, edge_id: str, queue: Queue | None = None) -> str:
    """``base`` (the studio's address) opening ``edge_id``, in ``queue`` when given."""
    url = f"{base}?edge={quote(edge_id, safe='')}"
    return url + (f"&queue={queue.slug}" if queue is not None else "")


def first_link(base: str, snap: Snapshot, queues: list[Queue]) -> str | None:
    """A link to the first edge of the most telling queue: a false loop the run kept, a
    right one it lost, else the first edge in log order; None without edges."""
    for queue in (Queue.kept_failure, Queue.rejected_success, Queue.log):
        edges = order(queue, snap) if queue in queues else []
        if edges:
            return link_url(base, edges[0], queue)
    return None


@dataclass(frozen=True)
class Opening:
    """Where a new tab starts.

    Attributes:
        queue: Its queue.
        order: The queue's edges.
        index: The linked edge's place in ``order``; None: start as a new tab does.
        note: Why the link could not be followed as asked ("" when it was).
    """

    queue: Queue
    order: list[str]
    index: int | None = None
    note: str = ""


def opening(link: Link, default: Queue, snap: Snapshot, queues: list[Queue]) -> Opening:
    """Where a tab opened by ``link`` starts.

    The linked edge is shown in the linked queue (else the tab's default one); an edge that
    queue does not hold is shown in log order instead, and the note says so. The tab shows
    the linked edge as it is (a step of 0 along the queue), labelled or held by another tab.
    """
    queue = link.queue if link.queue in queues else default
    note = ""
    if link.unknown_queue is not None or (link.queue is not None and link.queue is not queue):
        # The name is not echoed: it comes from whoever wrote the link.
        note = f"The link names a queue this studio does not offer: “{queue.value}” instead. "
    edges = order(queue, snap)
    if link.edge_id is None:
        return Opening(queue, edges, None, note.strip())
    if link.edge_id not in snap.edge_ids:
        return Opening(queue, edges, None, (note + "No such edge in this workspace.").strip())
    if link.edge_id not in edges:
        note += f"The edge is not in “{queue.value}”: shown in log order."
        queue, edges = Queue.log, order(Queue.log, snap)
    return Opening(queue, edges, edges.index(link.edge_id), note.strip())
