"""How many threads this process's own work may use."""

from __future__ import annotations

import os


def usable_threads(most: int = 4) -> int:
    """``OMP_NUM_THREADS`` where set (a Ray worker holding one CPU gets 1), else the CPUs this
    process may run on; at most ``most``."""
    named = os.environ.get("OMP_NUM_THREADS", "")
    if named.isdigit() and int(named) > 0:
        return int(named)
    return max(1, min(most, len(os.sched_getaffinity(0))))
