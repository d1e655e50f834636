"""One trainer per workspace: the lock a trainer holds, and whether someone else holds it.

A workspace's trainer holds an exclusive ``flock`` on ``models/.trainer.lock`` (the kernel
frees it when the process dies); a team store's holds an advisory lock in PostgreSQL (freed
with its connection). A second studio on the same store asks ``held_elsewhere`` before it
starts a trainer of its own, and uses the running one instead.
"""

from __future__ import annotations

import fcntl
from pathlib import Path
from typing import IO, Any

from vgm_studio.errors import InputError
from vgm_studio.labels.opening import open_store
from vgm_studio.trainer import registry

LOCK_NAME = ".trainer.lock"


def take_lock(workspace: Path) -> IO[Any]:
    """An exclusive lock on the workspace's trainer; the kernel frees it when the process dies.

    Raises:
        InputError: Another trainer holds it.
    """
    folder = workspace / registry.MODELS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    handle = (folder / LOCK_NAME).open("a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        raise InputError(workspace, "another trainer is running on this workspace") from None
    return handle


def held_elsewhere(workspace: Path, url: str | None = None) -> bool:
    """Whether a trainer (of another studio, or started alone) runs on this store now.

    Takes the lock and lets it go at once to find out; never raises (a store it cannot
    open says no, and the trainer started then reports what is wrong).
    """
    try:
        if url is not None:
            store = open_store(workspace, url, create=False)
            try:
                return bool(store.trainer_running())  # type: ignore[attr-defined]
            finally:
                store.close()
        path = workspace / registry.MODELS_DIR / LOCK_NAME
        if not path.exists():
            return False
        with path.open("a+") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(handle, fcntl.LOCK_UN)
            return False
    except (InputError, OSError):
        return False
