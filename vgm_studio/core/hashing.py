"""Content hashes: what a log, a bag folder or a checkpoint is, whatever its path."""

from __future__ import annotations

import hashlib
from pathlib import Path

_BLOCK = 1 << 20


def content_hash(path: Path) -> str:
    """sha256 of a file's bytes, or of a folder's files sorted by name, hex.

    For a folder (a ROS 2 bag) each file contributes its name (relative, ``/``-separated), its
    size and its bytes, so renaming or moving content between files changes the hash.
    """
    h = hashlib.sha256()
    if not path.is_dir():
        _update(h, path)
        return h.hexdigest()
    files = sorted((p for p in path.rglob("*") if p.is_file()), key=lambda p: p.relative_to(path))
    for file in files:
        h.update(file.relative_to(path).as_posix().encode("utf-8") + b"\0")
        h.update(file.stat().st_size.to_bytes(8, "little"))
        _update(h, file)
    return h.hexdigest()


def _update(h: hashlib._Hash, path: Path) -> None:
    with path.open("rb") as f:
        while block := f.read(_BLOCK):
            h.update(block)
