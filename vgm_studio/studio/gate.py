"""Who may open the studio: its own page, a same-origin websocket and, off this machine, a token.

viser serves its page and its websocket on one port through the ``websockets`` library, and a
page from any other site could open that websocket and read the edges (browsers do not apply
the same-origin policy to websockets; they only say where a page came from, in ``Origin``).
The studio therefore answers every HTTP request itself before viser does:

* the page (viser's client with one script added, see ``_KEY_GUARD_JS``) is served at ``/``,
  or only at ``/TOKEN`` when the studio requires a token;
* a websocket upgrade is accepted only when its ``Origin`` is the address the browser reached
  the studio by (the request's ``Host``), that host is a loopback name when the studio listens
  on loopback (so a DNS-rebound foreign name is refused), and its path carries the token when
  one is required. viser's client connects to the page's own path, so the token travels.

viser 1.1 builds its websockets server inside ``ViserServer.__init__`` and offers no hook for
this, so ``guarded_serve`` wraps ``websockets.asyncio.server.serve`` for exactly that call. It
also gives that server a quieter logger: websockets logs every connection that closes before
sending a request (a port check, a ``curl`` that gives up, a health probe) as an error with
three chained tracebacks, which would fill the studio's terminal with noise.
"""

from __future__ import annotations

import gzip
import http
import logging
import secrets
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import viser
import websockets.asyncio.server as ws_server
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from vgm_studio.studio.links import LINK_JS

LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1"})

# viser moves the camera while W/A/S/D/Q/E are held (its keyboard navigation listens on
# ``document``); the studio's label keys S, D, Q and E would drift the view a little on every
# press. Key events reach ``<html>`` before ``document``: stopping them there keeps viser's
# hotkeys (Mantine listens on ``<html>``) and starves only the camera. The mouse still moves it.
_KEY_GUARD_JS = """<script>
(() => {
  const cameraKeys = new Set(["KeyW", "KeyA", "KeyS", "KeyD", "KeyQ", "KeyE"]);
  document.documentElement.addEventListener("keydown", (event) => {
    if (cameraKeys.has(event.code)) event.stopPropagation();
  });
})();
</script>"""

_guard_lock = threading.Lock()

# The websockets server's logger (see ``_QuietHandshakes``); a child of websockets' own, so
# logging set up for websockets still reaches it.
_WS_LOG = logging.getLogger("websockets.server.studio")


def is_loopback(host: str) -> bool:
    return host.strip("[]") in LOOPBACK_HOSTS or host.startswith("127.")


def new_token() -> str:
    """A random token for the URL (URL-safe, 128 bits)."""
    return secrets.token_urlsafe(16)


@dataclass(frozen=True)
class Gate:
    """The studio's rules for requests.

    Attributes:
        listen_host: The interface the studio listens on.
        token: Required as the URL path (``/TOKEN``), or None for no token.
    """

    listen_host: str
    token: str | None = None

    @property
    def page_path(self) -> str:
        return f"/{self.token}" if self.token else "/"

    def url(self, port: int) -> str:
        """The page's address as a browser on this machine (or, off loopback, on another
        one) reaches it."""
        host = "localhost" if self.listen_host in ("127.0.0.1", "0.0.0.0") else self.listen_host
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{port}{self.page_path}"

    def _path_ok(self, path: str) -> bool:
        path = path.partition("?")[0]
        return path.rstrip("/") == self.page_path.rstrip("/")

    def refusal(self, request: Request) -> tuple[int, str] | None:
        """Why a request is refused, as (HTTP status, reason), or None to let it through."""
        if not self._path_ok(request.path):
            if self.token is None:
                return http.HTTPStatus.NOT_FOUND, "not found"
            return http.HTTPStatus.FORBIDDEN, "this studio needs its address with the token"
        if request.headers.get("Upgrade", "").lower() != "websocket":
            return None
        host = request.headers.get("Host", "")
        origin = request.headers.get("Origin")
        if origin is None:
            return http.HTTPStatus.FORBIDDEN, "a websocket without an Origin is refused"
        parts = urlsplit(origin)
        if parts.scheme not in ("http", "https") or parts.netloc.lower() != host.lower():
            return http.HTTPStatus.FORBIDDEN, "a page from another origin is refused"
        if is_loopback(self.listen_host) and not is_loopback(urlsplit(f"//{host}").hostname or ""):
            return http.HTTPStatus.FORBIDDEN, "this studio answers only on this machine"
        return None


@cache
def _page() -> tuple[bytes, bytes]:
    """viser's client page with the key guard added: (plain, gzipped)."""
    html = (Path(viser.__file__).parent / "client" / "build" / "index.html").read_text()
    head_end = html.index("</head>")
    page = html[:head_end] + _KEY_GUARD_JS + html[head_end:]
    # First in <head>: the worker viser's script makes must already be the linking one.
    head = page.index("<head>") + len("<head>")
    page = page[:head] + LINK_JS + page[head:]
    return page.encode(), gzip.compress(page.encode())


def _page_response(request: Request) -> Response:
    plain, zipped = _page()
    use_gzip = "gzip" in request.headers.get("Accept-Encoding", "")
    body = zipped if use_gzip else plain
    headers = Headers(
        {
            "Content-Type": "text/html; charset=utf-8",
            "Content-Length": str(len(body)),
            "Content-Encoding": "gzip" if use_gzip else "identity",
            "Cache-Control": "no-store",
            "Referrer-Policy": "no-referrer",  # the token is in the URL
        }
    )
    return Response(http.HTTPStatus.OK, "OK", headers, body)


def _process_request(gate: Gate) -> Callable[[Any, Request], Response | None]:
    def process(connection: Any, request: Request) -> Response | None:
        refused = gate.refusal(request)
        if refused is not None:
            response: Response = connection.respond(refused[0], refused[1] + "\n")
            return response
        if request.headers.get("Upgrade", "").lower() == "websocket":
            return None  # viser's handshake goes on
        return _page_response(request)

    return process


def _closed_early(exc: BaseException | None) -> bool:
    """Whether a failed handshake is a client that closed or reset before a whole request."""
    while exc is not None:
        if isinstance(exc, (EOFError, ConnectionError)):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


class _QuietHandshakes(logging.Filter):
    """Turns websockets' "opening handshake failed" and its tracebacks into one line.

    A client that closes before sending a request is routine (port checks, probes, a browser
    dropping a spare connection): one DEBUG line, unseen unless asked for. Any other failed
    handshake (a malformed request) is one WARNING line with the reason, no traceback: the
    cause is the client's, and nothing in the studio can be debugged from websockets' stack.
    Everything else websockets logs passes unchanged.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        if record.msg != "opening handshake failed" or not record.exc_info:
            return True
        exc = record.exc_info[1]
        if _closed_early(exc):
            _WS_LOG.debug("a connection closed before sending a request")
        else:
            cause = exc.__cause__ if exc is not None else None
            reason = f"{exc}" + (f" ({cause})" if cause is not None else "")
            _WS_LOG.warning("refused a connection: %s", reason)
        return False


_WS_LOG.addFilter(_QuietHandshakes())


@contextmanager
def guarded_serve(gate: Gate) -> Iterator[None]:
    """Within this block, a websockets server started (by viser) answers through ``gate``.

    viser starts its server in a thread and returns from ``ViserServer(...)`` only once it
    listens, so wrapping around that call covers it; the lock keeps two studios in one
    process from wrapping at once.
    """
    original = ws_server.serve

    def serve(*args: Any, **kwargs: Any) -> Any:
        kwargs["process_request"] = _process_request(gate)
        kwargs["logger"] = _WS_LOG
        return original(*args, **kwargs)

    with _guard_lock:
        ws_server.serve = serve  # type: ignore[assignment,misc]
        try:
            yield
        finally:
            ws_server.serve = original  # type: ignore[misc]
