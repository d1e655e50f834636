"""Worker processes: how they start, and how they end with the process that started them."""

from __future__ import annotations

import contextlib
import gc
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any


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


def keep_for_good() -> None:
    """Leaves every object this process holds now out of the collector's full passes, for
    good (``gc.freeze``): a worker's inputs (a log's scans), or a process about to end, whose
    last pass would walk its whole heap to free what the exit frees anyway (a second at the
    end of Intel's run)."""
    gc.freeze()


@contextlib.contextmanager
def long_lived() -> Iterator[None]:
    """Within the block, the objects that exist when it starts are left out of the
    collector's full passes, and put back after it.

    A run's log and the libraries' modules outlive the run, and every full pass walked them
    again: on Intel, 8 passes took 1.2 s of the main process's GIL, 0.4 s without them. Not
    nested: the inner block's end would put back the outer's too.
    """
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def start_worker(target: Callable[[Any, Any], None], first: object) -> tuple[Any, Any, Any]:
    """Starts ``target(to, back)`` in a spawned daemon process and puts ``first`` on ``to``;
    returns (process, to, back).

    ``first`` (a log's scans, typically) goes through the queue, whose thread writes it while
    the worker starts: as the process's arguments, the start waited on the worker's imports
    (1.2 s on Intel). A worker that died before reading it leaves it in the queue's pipe, and
    the run goes on without the worker: it must not wait at its exit to write it.

    Raises:
        OSError, RuntimeError: No process can start here.
    """
    context = spawn()
    to: Any = context.Queue()
    to.cancel_join_thread()
    back: Any = context.Queue()
    proc = context.Process(target=target, args=(to, back), daemon=True)
    proc.start()
    to.put(first)
    return proc, to, back
