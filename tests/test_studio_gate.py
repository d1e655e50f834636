"""Who may open a running studio: a real server, a real websocket client, real HTTP."""

from __future__ import annotations

import urllib.error
import urllib.request

import pytest
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from vgm_studio.labels import LabelStore
from vgm_studio.matching.edges import read_edges
from vgm_studio.studio.app import Studio, StudioConfig
from vgm_studio.studio.gate import is_loopback

PROTOCOL = f"viser-v{viser.__version__}"


@pytest.fixture
def running(office_edges, tmp_path, request):
    """A studio on a free port; ``request.param`` is (host, token)."""
    from benchmarks.studio_browser import free_port

    host, token = getattr(request, "param", ("127.0.0.1", None))
    store = LabelStore(tmp_path / "ws")
    store.add_edges(read_edges(office_edges))
    studio = Studio(store, StudioConfig(host=host, port=free_port(), token=token))
    studio.start()
    yield studio
    studio.stop()
    store.close()


def _ws(studio: Studio, origin: str | None, path: str = "/") -> None:
    """Opens and closes a websocket to the studio; raises InvalidStatus when refused."""
    url = f"ws://127.0.0.1:{studio.config.port}{path}"
    kwargs = {"origin": origin} if origin is not None else {}
    with connect(url, subprotocols=[PROTOCOL], open_timeout=10, **kwargs) as ws:  # type: ignore[arg-type]
        ws.recv(timeout=10)  # the studio talks to an accepted client at once


def test_a_foreign_origin_is_refused_and_the_studios_own_is_served(running):
    port = running.config.port
    for foreign in ("http://evil.example", f"http://evil.example:{port}", "null"):
        with pytest.raises(InvalidStatus) as refused:
            _ws(running, foreign)
        assert refused.value.response.status_code == 403
    with pytest.raises(InvalidStatus):
        _ws(running, None)  # no Origin: not a page of this studio
    _ws(running, f"http://127.0.0.1:{port}")  # connects and receives


def test_the_page_is_served_with_the_key_guard(running):
    body = urllib.request.urlopen(running.url, timeout=10).read().decode()
    assert "cameraKeys" in body and "stopPropagation" in body


@pytest.mark.parametrize("running", [("0.0.0.0", None)], indirect=True)
def test_off_loopback_a_token_is_made_and_required(running):
    token = running.config.token
    assert token and len(token) >= 16 and running.url.endswith(f"/{token}")
    port = running.config.port
    origin = f"http://127.0.0.1:{port}"
    with pytest.raises(InvalidStatus):
        _ws(running, origin)  # right origin, no token
    with pytest.raises(InvalidStatus):
        _ws(running, origin, "/not-the-token")
    _ws(running, origin, f"/{token}")
    with pytest.raises(urllib.error.HTTPError) as page:
        urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10)
    assert page.value.code == 403
    assert urllib.request.urlopen(f"http://127.0.0.1:{port}/{token}", timeout=10).status == 200


@pytest.mark.parametrize("running", [("127.0.0.1", "s3cret-token-given")], indirect=True)
def test_a_given_token_is_used_on_loopback_too(running):
    origin = f"http://localhost:{running.config.port}"
    with pytest.raises(InvalidStatus):
        _ws(running, origin)
    assert running.url.endswith("/s3cret-token-given")


def test_loopback_names():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("[::1]")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.4")


def test_a_rebound_name_is_refused_on_loopback():
    from websockets.datastructures import Headers
    from websockets.http11 import Request

    from vgm_studio.studio.gate import Gate

    def upgrade(host: str) -> Request:
        headers = {"Host": host, "Origin": f"http://{host}", "Upgrade": "websocket"}
        return Request("/", Headers(headers))

    gate = Gate("127.0.0.1")
    # A page on evil.example whose name now resolves to 127.0.0.1: same-origin, wrong name.
    assert gate.refusal(upgrade("evil.example:8080")) is not None
    assert gate.refusal(upgrade("localhost:8080")) is None
    assert gate.refusal(upgrade("[::1]:8080")) is None
    assert Gate("0.0.0.0", "t").refusal(upgrade("studio.lan:8080")) is not None  # no token
    ok = upgrade("studio.lan:8080")
    assert Gate("0.0.0.0", "t").refusal(Request("/t", ok.headers)) is None


def test_only_the_page_is_served():
    from websockets.datastructures import Headers
    from websockets.http11 import Request

    from vgm_studio.studio.gate import Gate

    page = Headers({"Host": "localhost:8080"})
    assert Gate("127.0.0.1").refusal(Request("/", page)) is None
    assert Gate("127.0.0.1").refusal(Request("/etc/passwd", page)) == (404, "not found")
    assert Gate("0.0.0.0", "t").refusal(Request("/", page))[0] == 403  # type: ignore[index]


_SERVE_SCRIPT = """
import sys, time
from pathlib import Path
from vgm_studio.labels import LabelStore
from vgm_studio.studio.app import Studio, StudioConfig
studio = Studio(LabelStore(Path(sys.argv[1])), StudioConfig(port=int(sys.argv[2])))
studio.start()
print("listening", flush=True)
time.sleep(60)
"""


def test_a_connection_closed_without_a_request_prints_no_traceback(tmp_path):
    """A port check or a probe (connect, then close) leaves the studio's terminal clean."""
    import socket
    import subprocess
    import sys
    import time

    from benchmarks.studio_browser import free_port

    port = free_port()
    server = subprocess.Popen(
        [sys.executable, "-c", _SERVE_SCRIPT, str(tmp_path / "ws"), str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert server.stdout is not None
        while "listening" not in server.stdout.readline():  # after viser's banner
            assert server.poll() is None, "the studio did not start"
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass  # connect and close: what a port check does
        with socket.create_connection(("127.0.0.1", port), timeout=5) as half:
            half.sendall(b"GET / HT")  # a client that gives up mid-request
        time.sleep(1.0)
        # The studio still answers afterwards.
        assert urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10).status == 200
    finally:
        server.terminate()
        _, stderr = server.communicate(timeout=30)
    assert "Traceback" not in stderr
    assert "handshake failed" not in stderr
