"""What an audit reads: a pose graph, and a scan for each of its vertices.

A g2o graph may carry its scans (``ROBOTLASER1`` after each vertex); otherwise they come from
a log or bag, tied to the vertices by a TUM file of the vertices' timestamps
(``--vertex-times``) or by vertex id = scan index (``--vertex-index scan``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.datasets.g2o import PoseGraphFile, graph_log
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.datasets.tum import TumTrajectory
from vgm_studio.errors import InputError


@dataclass
class AuditInput:
    """A graph and its scans.

    Attributes:
        graph: The graph as its file gave it.
        log: The scans: the graph's own (one per vertex), or the named log's.
        vertex_scans: (V,) each vertex's scan, by index in ``log``.
        scan_poses: (N, 3) a pose for every scan of ``log``: which scans are a vertex's
            neighbours in a local map, and how the vertices' corrections reach the scans
            between them (the log's odometry where it has one, else the vertices' poses
            carried along by index).
    """

    graph: PoseGraphFile
    log: ScanLog
    vertex_scans: NDArray[np.int64]
    scan_poses: NDArray[np.float64]

    @property
    def inline(self) -> bool:
        """The graph's own scans are the log: vertex k is scan k."""
        return bool(np.array_equal(self.vertex_scans, np.arange(len(self.log))))


def inline_input(graph: PoseGraphFile) -> AuditInput:
    """The graph's own scans, one per vertex.

    Raises:
        InputError: The graph has no scans (it needs ``--scans``).
    """
    if graph.scans is None:
        raise InputError(
            graph.path,
            "has no scans (no ROBOTLASER1 lines): name the log or bag they come from with "
            "--scans, and tie them to the vertices with --vertex-times or --vertex-index scan",
        )
    vertices = np.arange(len(graph), dtype=np.int64)
    return AuditInput(graph, graph_log(graph), vertices, graph.poses.copy())


def by_index(graph: PoseGraphFile, log: ScanLog) -> AuditInput:
    """Vertex id = scan index in the log.

    Raises:
        InputError: A vertex id past the log's last scan.
    """
    too_far = np.flatnonzero(graph.ids >= len(log))
    if len(too_far):
        k = int(too_far[0])
        raise InputError(
            graph.path,
            f"vertex {graph.ids[k]} has no scan: {log.path} has {len(log)} scans "
            "(--vertex-index scan ties vertex id to scan index)",
            int(graph.lines[k]),
        )
    return _tied(graph, log, graph.ids.astype(np.int64))


def by_times(
    graph: PoseGraphFile, log: ScanLog, times: TumTrajectory, path: Path, tolerance: float
) -> AuditInput:
    """Each vertex's scan is the log's scan nearest its timestamp (line k of the TUM file is
    vertex k, in the order of the ids).

    Raises:
        InputError: The TUM file has another number of poses than the graph has vertices, or
            a timestamp with no scan within ``tolerance`` seconds.
    """
    if len(times.timestamps) != len(graph):
        raise InputError(
            path,
            f"has {len(times.timestamps)} poses but {graph.path} has {len(graph)} vertices "
            "(one line per vertex, in the order of their ids)",
        )
    stamps = log.timestamps
    order = np.argsort(stamps, kind="stable")
    sorted_stamps = stamps[order]
    after = np.clip(np.searchsorted(sorted_stamps, times.timestamps), 0, len(stamps) - 1)
    before = np.maximum(after - 1, 0)
    nearer = np.abs(times.timestamps - sorted_stamps[before]) <= np.abs(
        sorted_stamps[after] - times.timestamps
    )
    scans = order[np.where(nearer, before, after)]
    gap = np.abs(stamps[scans] - times.timestamps)
    far = np.flatnonzero(~(gap <= tolerance))
    if len(far):
        k = int(far[0])
        raise InputError(
            path,
            f"vertex {graph.ids[k]}'s time {times.timestamps[k]:.6f} has no scan of "
            f"{log.path} within {tolerance} s (nearest {gap[k]:.3f} s off)",
            int(times.lines[k]),
        )
    return _tied(graph, log, scans.astype(np.int64))


def _tied(graph: PoseGraphFile, log: ScanLog, scans: NDArray[np.int64]) -> AuditInput:
    if len(scans) > 1 and np.any(np.diff(scans) <= 0):
        k = int(np.flatnonzero(np.diff(scans) <= 0)[0]) + 1
        raise InputError(
            graph.path,
            f"vertex {graph.ids[k]} is tied to scan {scans[k]}, not after vertex "
            f"{graph.ids[k - 1]}'s scan {scans[k - 1]}: vertices must follow the log's order",
            int(graph.lines[k]),
        )
    return AuditInput(graph, log, scans, _scan_poses(graph, log, scans))


def _scan_poses(
    graph: PoseGraphFile, log: ScanLog, scans: NDArray[np.int64]
) -> NDArray[np.float64]:
    odometry = log.odometry_poses()
    if odometry is not None:
        return odometry
    # No odometry in the log: each scan takes the nearest earlier vertex's pose. Local maps
    # match their neighbours from it, and the scans between vertices stay with the vertex.
    owner = np.clip(np.searchsorted(scans, np.arange(len(log)), side="right") - 1, 0, None)
    return np.asarray(graph.poses[owner], dtype=np.float64)
