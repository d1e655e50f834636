"""Worker processes: how they start, and how they end with the process that started them."""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time


def spawn() -> multiprocessing.context.SpawnContext:
    """How worker processes start. Not fork: the parent runs threads (kiss-icp's, torch's)
    whose locks a fork would copy held.

    Raises:
        OSError, RuntimeError: No processes here.
    """
    return multiprocessing.get_context("spawn")


def exit_with_parent() -> None:
    """Ends this worker process when its parent is gone: a parent killed outright (kill -9)
    closes no pipe the worker waits on, and it would wait on.

    The parent is the one that spawned this worker, not the one it has now: a parent killed
    while the worker was still starting has already left it to init.

    Ctrl-C at a terminal reaches the whole process group; the worker leaves it to its
    parent, which stops it, rather than print a traceback of its own."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    spawned_by = multiprocessing.parent_process()
    parent = spawned_by.pid if spawned_by is not None else os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
