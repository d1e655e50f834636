"""Stage 1: logs → scans. One reader per format; ``open_log`` picks by path."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from vgm_studio.datasets.carmen import read_carmen
from vgm_studio.datasets.g2o import graph_log, looks_like_graph, read_graph
from vgm_studio.datasets.mount import mount_from_options
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.scans import Scan, ScanLog, with_mount
from vgm_studio.errors import InputError, require_utf8_path

__all__ = ["ReadOptions", "Scan", "ScanLog", "open_log"]


def open_log(path: str | Path, options: ReadOptions | None = None) -> ScanLog:
    """Reads a CARMEN log (a file), a ROS bag (a ``.bag`` file or a ROS 2 bag folder) or the
    scans of a g2o pose graph (``ROBOTLASER1`` after each vertex; ``datasets.g2o``).

    The laser's mount in ``options`` places the scans in the base frame; without one, the mount
    a CARMEN log declares in its PARAM lines does (``datasets.carmen_mount``). A CARMEN log's pose
    fields are the laser's pose (ROBOTLASER1 says so; CARMEN writes FLASER's the same way), so
    they move to the base with the mount and the world stays where the log put it.
    """
    path = Path(path)
    require_utf8_path(path)
    if not path.exists():
        raise InputError(path, "no such file or folder")
    if path.is_dir() or path.suffix in {".bag", ".db3", ".mcap"}:
        from vgm_studio.datasets.rosbag import read_rosbag

        return read_rosbag(path, options)
    if looks_like_graph(path):
        return graph_log(read_graph(path))
    log = read_carmen(path, options)
    given = (
        None if options is None else mount_from_options(options.laser_pose, options.laser_flipped)
    )
    if given is not None:
        return with_mount(log, given, "given by --laser-pose/--laser-flipped", poses_of_laser=True)
    if log.declared_mount is None:
        return log
    declared, said = log.declared_mount
    if declared.is_base:
        return replace(log, mount_source=said)
    return with_mount(log, declared, said, poses_of_laser=True)
