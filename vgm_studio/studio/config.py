"""How a studio serves: its settings, and the checks made before it listens."""

from __future__ import annotations

import getpass
import socket
from dataclasses import dataclass, field

from vgm_studio.errors import InputError
from vgm_studio.studio.queues import Queue
from vgm_studio.vgm.grid import VGMParams


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
        token: Required in the URL's path (``http://HOST:PORT/TOKEN``); None asks for none on
            loopback, and ``start`` makes one up for any other host.
    """

    host: str = "127.0.0.1"
    port: int = 8080
    annotator: str = field(default_factory=default_annotator)
    queue: Queue = Queue.unlabelled
    vgm: VGMParams = field(default_factory=VGMParams)
    title: str = "VGM Studio"
    token: str | None = None


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
