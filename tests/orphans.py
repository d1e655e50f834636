"""Whether a worker process went after its parent was killed outright (kill -9)."""

from __future__ import annotations

import os
import time


def gone_within(pid: int, seconds: float) -> bool:
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
