"""Checkpoints loaded once per process, for processes that validate many logs.

A fleet worker runs the whole pipeline log after log; loading the network for every log
would cost more than validating a short one. The cache is keyed by the file's resolved path,
size and modification time, so a checkpoint replaced on disk is loaded again.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from vgm_studio.model.validator import Validator

_LOCK = threading.Lock()
_LOADED: dict[tuple[str, int, int], Validator] = {}
_LOADS = [0]


def shared_validator(path: Path) -> Validator:
    """The validator of a checkpoint, loaded on first use in this process and kept.

    Raises:
        InputError: The checkpoint is missing, unreadable or not a VGM Studio checkpoint.
    """
    from vgm_studio.model.validator import Validator

    try:
        stat = path.stat()
        key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    except OSError:
        return Validator.load(path)  # says what is wrong with the path, as a plain load does
    with _LOCK:
        validator = _LOADED.get(key)
        if validator is None:
            validator = _LOADED[key] = Validator.load(path)
            _LOADS[0] += 1
        return validator


def load_count() -> int:
    """How many checkpoints this process has loaded through the cache.

    A fleet worker reports it in each row: one per model, however many logs it ran.
    """
    return _LOADS[0]
