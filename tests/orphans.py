"""Whether a worker process goes when its parent is killed outright (kill -9)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path


def assert_worker_goes_with_its_parent(parent_script: str, log: Path) -> None:
    """Runs ``parent_script`` (given ``log`` as its argument; it prints its worker's pid and
    waits), kills it outright once the worker is alive, and asserts the worker goes within
    20 s."""
    parent = subprocess.Popen(
        [sys.executable, "-c", parent_script, str(log)], stdout=subprocess.PIPE, text=True
    )
    assert parent.stdout is not None
    worker = int(parent.stdout.readline())
    os.kill(worker, 0)  # alive
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    if not _gone_within(worker, 20):
        os.kill(worker, signal.SIGKILL)
        raise AssertionError("the worker outlived its parent by 20 s")


def _gone_within(pid: int, seconds: float) -> bool:
    """Whether process ``pid`` ends within ``seconds``: gone, or a zombie (a worker that went
    is one until someone reaps it, and with its parent killed nobody but init will)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        with open(f"/proc/{pid}/stat") as stat:
            if stat.read().split(")")[-1].split()[0] == "Z":
                return True
        time.sleep(0.2)
    return False


def stream_parent(module: str, name: str) -> str:
    """A parent script for ``assert_worker_goes_with_its_parent`` that starts the worker of
    ``module.name``, a stream made from a log's scans, which may be keyframes, and a
    keyframe step (``BetweenStream``, ``OdometryStream``)."""
    return f"""
import sys, time
import numpy as np
from vgm_studio.datasets import open_log
from {module} import {name}

log = open_log(sys.argv[1])
stream = {name}(log.scans, np.ones(len(log), dtype=bool), (0.5, 20.0))
print(stream._proc.pid, flush=True)
time.sleep(600)
"""
