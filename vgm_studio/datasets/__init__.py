"""Stage 1: logs → scans. One reader per format; ``open_log`` picks by path."""

from __future__ import annotations

from pathlib import Path

from vgm_studio.datasets.carmen import read_carmen
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.scans import Scan, ScanLog
from vgm_studio.errors import InputError, require_utf8_path

__all__ = ["ReadOptions", "Scan", "ScanLog", "open_log"]


def open_log(path: str | Path, options: ReadOptions | None = None) -> ScanLog:
    """Reads a CARMEN log (a file) or a ROS bag (a ``.bag`` file or a ROS 2 bag folder)."""
    path = Path(path)
    require_utf8_path(path)
    if not path.exists():
        raise InputError(path, "no such file or folder")
    if path.is_dir() or path.suffix in {".bag", ".db3", ".mcap"}:
        from vgm_studio.datasets.rosbag import read_rosbag

        return read_rosbag(path, options)
    return read_carmen(path, options)
