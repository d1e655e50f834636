"""What ``slam`` and ``audit`` both write: maps (PNG, ROS), the recording, the trajectory, the
graph and the JSON document, from a run's ``SlamResult``."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.atomic import write_json_atomically
from vgm_studio.datasets.g2o import G2oEdge, information_of, write_g2o
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.datasets.tum import write_tum
from vgm_studio.errors import InputError
from vgm_studio.graph.metrics import RelationErrors
from vgm_studio.maps.config import MapConfig
from vgm_studio.maps.occupancy import OccupancyGrid
from vgm_studio.maps.png import write_maps
from vgm_studio.maps.ros_map import write_ros_map
from vgm_studio.services import Say, Voice
from vgm_studio.slam.pipeline import SlamResult
from vgm_studio.slam.report import LOOP_COLOURS, loop_segments, run_maps


@dataclass(frozen=True)
class RunFiles:
    """The files a run's result can be written as, each where asked.

    Attributes:
        maps: A folder for the maps (each trajectory's, and all together) as PNG.
        record: A rerun recording.
        spawn: Open the rerun viewer on the run.
        trajectory: Every scan's pose of the after graph as a TUM file (``datasets.tum``).
        ros_map: A folder for the after map as ROS map_server loads it (``maps.ros_map``).
        g2o: The after graph as a g2o 2D file, each keyframe with its scan
            (``datasets.g2o``).
    """

    maps: Path | None = None
    record: Path | None = None
    spawn: bool = False
    trajectory: Path | None = None
    ros_map: Path | None = None
    g2o: Path | None = None


def write_run_files(
    log: ScanLog,
    result: SlamResult,
    errors: dict[str, RelationErrors] | None,
    config: MapConfig,
    files: RunFiles,
    voice: Voice,
) -> None:
    """Writes what ``files`` asks for, each timed into the result's seconds.

    Raises:
        InputError: A file cannot be written.
    """
    _write_maps_and_recording(log, result, errors, config, files, voice.say)
    if files.trajectory is not None:
        _write_trajectory(files.trajectory, log, result, voice)
    if files.g2o is not None:
        _write_graph(files.g2o, log, result, voice.say)


def _write_maps_and_recording(
    log: ScanLog,
    result: SlamResult,
    errors: dict[str, RelationErrors] | None,
    config: MapConfig,
    outputs: RunFiles,
    say: Say,
) -> None:
    """The maps (PNG, ROS) and the recording, each timed into the run's seconds."""
    maps: dict[str, OccupancyGrid] | None = None
    wanted = (outputs.maps, outputs.record, outputs.ros_map)
    if any(out is not None for out in wanted) or outputs.spawn:
        t = time.perf_counter()
        maps = run_maps(log, result, config)
        result.seconds["maps"] = time.perf_counter() - t
        for name, grid in maps.items():
            if grid.resolution > config.resolution:
                say(f"the {name} map is {grid.resolution:.3f} m a cell, to fit its size")
    if outputs.maps is not None and maps is not None:
        edges = ("after", loop_segments(result), LOOP_COLOURS)
        for path in write_maps(outputs.maps, maps, edges):
            say(f"wrote {path}")
    if outputs.ros_map is not None and maps is not None:
        for path in write_ros_map(outputs.ros_map, maps["after"]):
            say(f"wrote {path}")
    if outputs.record is not None or outputs.spawn:
        # Here, not at the top: rerun's import costs every run half a second, most never record.
        from vgm_studio.recording import write_recording

        t = time.perf_counter()
        write_recording(log, result, maps or {}, errors, outputs.record, outputs.spawn)
        result.seconds["recording"] = time.perf_counter() - t
        if outputs.record is not None:
            say(f"wrote {outputs.record}")


def _write_trajectory(path: Path, log: ScanLog, result: SlamResult, voice: Voice) -> None:
    """Every scan's pose of the after graph, at its timestamp, as a TUM file."""
    times = log.timestamps
    problem = _time_problem(times)
    if problem is not None:
        # A TUM file needs increasing times; the scan index keeps the poses in order and
        # still pairs them with another file written from this log.
        voice.warn(f"{log.path}: {problem}; {path} takes the scan index as each pose's time")
        times = np.arange(len(times), dtype=np.float64)
    poses = result.scan_poses(result.after.poses)
    write_tum(path, times, poses)
    voice.say(f"wrote {path} ({len(poses)} scan poses, TUM: timestamp x y z qx qy qz qw)")


def _write_graph(path: Path, log: ScanLog, result: SlamResult, say: Say) -> None:
    """The after graph as g2o: its optimised keyframe poses, each with its scan, and the very
    factors it was optimised over (the odometry fallbacks included), so that another
    optimiser given the file solves the same problem."""
    edges = [
        G2oEdge(e.a, e.b, e.measurement, information_of(e.covariance)) for e in result.after_edges
    ]
    scans = [log.scans[i] for i in result.keyframes]
    try:
        write_g2o(path, result.after.poses, edges, scans)
    except OSError as exc:
        raise InputError(path, f"cannot write ({exc.strerror or exc})") from None
    say(f"wrote {path} ({len(scans)} keyframes, {len(edges)} edges, g2o)")


def _time_problem(times: NDArray[np.float64]) -> str | None:
    """Why a log's scan timestamps cannot be a trajectory's times; None where they can."""
    bad = np.flatnonzero(~np.isfinite(times))
    if len(bad):
        return f"{len(bad)} scans have no timestamp (the first is scan {bad[0]})"
    back = np.flatnonzero(np.diff(times) <= 0)
    if len(back):
        return (
            f"the scan timestamps do not increase at {len(back)} scans "
            f"(the first is scan {back[0] + 1})"
        )
    return None


def write_json(path: Path, doc: dict[str, Any]) -> None:
    try:
        write_json_atomically(path, doc)
    except OSError as exc:
        raise InputError(path, f"cannot write ({exc.strerror or exc})") from None
