"""A throwaway PostgreSQL server from Debian's binaries, on loopback, for tests and benchmarks.

``initdb`` and ``pg_ctl`` refuse to run as root, so under root they run as the ``postgres``
user, in a folder of their own outside pytest's (root-only) temporary folders.
"""

from __future__ import annotations

import itertools
import os
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path


def pg_bin() -> Path | None:
    """The newest installed PostgreSQL's bin folder, or None."""
    found = sorted(Path("/usr/lib/postgresql").glob("*/bin/pg_ctl"))
    return found[-1].parent if found else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class LocalPostgres:
    """One server: ``start``, ``new_database``, ``restart``, ``stop``.

    Args:
        bindir: Where ``initdb``, ``pg_ctl`` and ``createdb`` are.
    """

    def __init__(self, bindir: Path) -> None:
        self.bindir = bindir
        self.folder = Path(tempfile.mkdtemp(prefix="vgm-pg-"))
        self.root = os.geteuid() == 0
        self.user = "postgres" if self.root else os.environ.get("USER", "postgres")
        if self.root:
            shutil.chown(self.folder, "postgres")
        self.port = _free_port()
        data = self.folder / "data"
        opts = f"-p {self.port} -k {self.folder} -c listen_addresses=127.0.0.1"
        self._ctl = f"{bindir}/pg_ctl -D {data} -l {self.folder}/log -w -o '{opts}'"
        self._initdb = f"{bindir}/initdb -D {data} -U {self.user} -A trust --no-sync"
        self._names = itertools.count()

    def _as_owner(self, command: str) -> None:
        args = ["su", "postgres", "-s", "/bin/sh", "-c", command] if self.root else ["sh", "-c"]
        if not self.root:
            args.append(command)
        subprocess.run(args, check=True, capture_output=True, timeout=120)

    def start(self) -> None:
        self._as_owner(f"{self._initdb} >/dev/null")
        self._as_owner(f"{self._ctl} start >/dev/null")

    def new_database(self, name: str = "t") -> str:
        """Makes an empty database; returns its URL."""
        db = f"{name}_{next(self._names)}"
        createdb = [str(self.bindir / "createdb"), "-h", "127.0.0.1", "-p", str(self.port)]
        subprocess.run([*createdb, "-U", self.user, db], check=True, capture_output=True)
        return f"postgresql://{self.user}@127.0.0.1:{self.port}/{db}"

    def restart(self) -> None:
        """``pg_ctl restart -m fast``: every connection is cut, committed data stays."""
        self._as_owner(f"{self._ctl} -m fast restart >/dev/null")

    def stop(self) -> None:
        self._as_owner(f"{self._ctl} -m immediate stop >/dev/null")
        shutil.rmtree(self.folder, ignore_errors=True)
