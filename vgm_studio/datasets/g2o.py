"""Pose graphs other SLAM systems write: g2o 2D (``VERTEX_SE2``, ``EDGE_SE2``, ``FIX``, with
``ROBOTLASER1`` scans) and TORO / MRPT ``.graph`` (``VERTEX2``, ``EDGE2``).

g2o's lines::

    VERTEX_SE2 id x y θ
    ROBOTLASER1 …               (CARMEN's layout; the scan of the vertex before it)
    FIX id
    EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33     (the information's upper triangle)

TORO's edge writes the information in another order: ``EDGE2 i j dx dy dθ I11 I12 I22 I33
I13 I23``. Vertices are kept in the order of their ids (index k is the k-th smallest id), so
consecutive indices are consecutive poses. Every line the reader does not know, a malformed
number, a NaN, an edge to a vertex that is not there, a vertex no edge names and an
information matrix that is not positive definite stop it with one line naming file:line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from vgm_studio.atomic import write_text_atomically
from vgm_studio.core import se2
from vgm_studio.core.hashing import content_hash
from vgm_studio.datasets.carmen import format_robotlaser
from vgm_studio.datasets.carmen_lines import LineParser, RawScan, parse_robotlaser, quote_token
from vgm_studio.datasets.mount import LaserMount
from vgm_studio.datasets.scans import Scan, ScanLog
from vgm_studio.errors import InputError

GraphFormat = Literal["g2o", "toro"]

# Upper-triangle positions (row, column) of the six information entries, in file order.
_G2O_ORDER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_TORO_ORDER = ((0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2))
# What a CARMEN log holds: given where a graph is due, say so rather than quote a stray line.
_LOG_MESSAGES = frozenset({"PARAM", "SYNC", "FLASER", "RLASER", "ODOM", "TRUEPOS", "NEFF"})
_KNOWN = {
    "g2o": ("VERTEX_SE2", "EDGE_SE2", "FIX", "ROBOTLASER1"),
    "toro": ("VERTEX2", "EDGE2", "FIX"),
}


@dataclass(frozen=True)
class G2oEdge:
    """A relative-pose constraint of a graph file.

    Attributes:
        a: Index of the first vertex (0..V-1, in the order of the file's ids).
        b: Index of the second vertex.
        measurement: (3,) pose of b in a's frame.
        information: (3, 3) inverse covariance of the measurement.
        line: The line it was read from (0 for an edge made, not read).
    """

    a: int
    b: int
    measurement: NDArray[np.float64]
    information: NDArray[np.float64]
    line: int = 0

    @property
    def covariance(self) -> NDArray[np.float64]:
        return np.asarray(np.linalg.inv(self.information), dtype=np.float64)


@dataclass
class PoseGraphFile:
    """A pose graph as its file gave it.

    Attributes:
        path: The file.
        format: ``g2o`` or ``toro``.
        ids: (V,) the file's vertex ids, by index.
        poses: (V, 3) the vertices' poses as written (the writer's estimate).
        edges: The constraints, in file order.
        fixed: Index of the vertex held fixed (``FIX``), None where the file fixes none.
        scans: One scan per vertex where every vertex has a ``ROBOTLASER1`` line, else None.
        lines: (V,) the line each vertex was read from.
        content_hash: The file's hash.
    """

    path: Path
    format: GraphFormat
    ids: NDArray[np.int64]
    poses: NDArray[np.float64]
    edges: list[G2oEdge]
    fixed: int | None
    scans: list[Scan] | None
    lines: NDArray[np.int64]
    content_hash: str

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def timestamps(self) -> NDArray[np.float64]:
        """(V,) the scans' timestamps, NaN without scans."""
        if self.scans is None:
            return np.full(len(self), np.nan)
        return np.array([s.timestamp for s in self.scans], dtype=np.float64)


def looks_like_graph(path: Path) -> bool:
    """Whether the file's first data line is a g2o or TORO vertex or edge."""
    try:
        with path.open("r", encoding="utf-8", errors="replace") as f:
            for text in f:
                tokens = text.split()
                if tokens and not tokens[0].startswith("#"):
                    return tokens[0] in {"VERTEX_SE2", "EDGE_SE2", "VERTEX2", "EDGE2", "FIX"}
    except OSError:
        return False
    return False


class _Reader:
    """The state of one read: vertices by id, edges, the scan lines after each vertex."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.format: GraphFormat | None = None
        self.vertices: dict[int, tuple[NDArray[np.float64], int]] = {}
        self.raw_edges: list[tuple[int, int, NDArray[np.float64], NDArray[np.float64], int]] = []
        self.fixed: list[tuple[int, int]] = []
        self.scans: dict[int, RawScan] = {}
        self.last_vertex: int | None = None

    def line(self, lineno: int, tokens: list[str]) -> None:
        kind = tokens[0]
        p = LineParser(self.path, lineno, tokens)
        fmt: GraphFormat = "toro" if kind in ("VERTEX2", "EDGE2") else "g2o"
        if kind not in _KNOWN["g2o"] + _KNOWN["toro"]:
            if kind in _LOG_MESSAGES and not self.vertices:
                raise InputError(
                    self.path,
                    f"{kind} is a CARMEN log's line: this is a log, not a pose graph (give the "
                    "graph, and this log with --scans)",
                    line=lineno,
                )
            raise InputError(
                self.path,
                f"{quote_token(kind)} is not a line of a 2D pose graph (g2o: VERTEX_SE2, "
                "EDGE_SE2, FIX, ROBOTLASER1; TORO: VERTEX2, EDGE2)",
                line=lineno,
            )
        if kind != "FIX":
            if self.format is not None and fmt != self.format:
                raise p.fail(f"a {fmt} line in a {self.format} graph")
            self.format = fmt
        if kind in ("VERTEX_SE2", "VERTEX2"):
            self._vertex(p)
        elif kind in ("EDGE_SE2", "EDGE2"):
            self._edge(p, _G2O_ORDER if fmt == "g2o" else _TORO_ORDER)
        elif kind == "FIX":
            p.need(2, "a vertex id")
            self.fixed += [(_id(p, i), lineno) for i in range(1, len(tokens))]
        else:
            self._scan(p)

    def _vertex(self, p: LineParser) -> None:
        p.exact((5,), "a vertex is its id and x y θ")
        vid = _id(p, 1)
        if vid in self.vertices:
            raise p.fail(f"vertex {vid} again (first on line {self.vertices[vid][1]})")
        self.vertices[vid] = (p.pose(2), p.lineno)
        self.last_vertex = vid

    def _edge(self, p: LineParser, order: tuple[tuple[int, int], ...]) -> None:
        p.exact((12,), "an edge is two ids, dx dy dθ and six information entries")
        a, b = _id(p, 1), _id(p, 2)
        if a == b:
            raise p.fail(f"an edge from vertex {a} to itself")
        measurement = p.pose(3)
        info = np.zeros((3, 3))
        for k, (r, c) in enumerate(order):
            info[r, c] = info[c, r] = p.finite(6 + k, "an information entry")
        if not _positive_definite(info):
            raise p.fail("the information matrix is not positive definite")
        self.raw_edges.append((a, b, measurement, info, p.lineno))

    def _scan(self, p: LineParser) -> None:
        if self.last_vertex is None:
            raise p.fail("a scan before any vertex (ROBOTLASER1 follows its VERTEX_SE2)")
        if self.last_vertex in self.scans:
            raise p.fail(f"a second scan for vertex {self.last_vertex}")
        self.scans[self.last_vertex] = parse_robotlaser(p)

    def graph(self) -> PoseGraphFile:
        if not self.vertices:
            raise InputError(self.path, "no vertices: not a g2o or TORO pose graph")
        ids = np.array(sorted(self.vertices), dtype=np.int64)
        index = {int(v): k for k, v in enumerate(ids)}
        named: set[int] = set()
        edges = []
        for a, b, z, info, line in self.raw_edges:
            for v in (a, b):
                if v not in index:
                    raise InputError(
                        self.path, f"edge to vertex {v}, which is not in the graph", line
                    )
            named.update((a, b))
            edges.append(G2oEdge(index[a], index[b], z, info, line))
        if len(ids) > 1:
            for v in ids:
                if int(v) not in named:
                    raise InputError(
                        self.path,
                        f"vertex {v} is named by no edge: nothing ties it to the rest of the graph",
                        self.vertices[int(v)][1],
                    )
        fixed = None
        for vid, line in self.fixed:
            if vid not in index:
                raise InputError(
                    self.path, f"FIX names vertex {vid}, which is not in the graph", line
                )
            fixed = index[vid] if fixed is None else fixed
        return PoseGraphFile(
            path=self.path,
            format=self.format or "g2o",
            ids=ids,
            poses=np.array([self.vertices[int(v)][0] for v in ids], dtype=np.float64),
            edges=edges,
            fixed=fixed,
            scans=self._vertex_scans(ids),
            lines=np.array([self.vertices[int(v)][1] for v in ids], dtype=np.int64),
            content_hash=content_hash(self.path),
        )

    def _vertex_scans(self, ids: NDArray[np.int64]) -> list[Scan] | None:
        if not self.scans:
            return None
        out = []
        for k, vid in enumerate(ids):
            raw = self.scans.get(int(vid))
            pose, line = self.vertices[int(vid)]
            if raw is None:
                raise InputError(
                    self.path,
                    f"vertex {vid} has no ROBOTLASER1 line though other vertices do",
                    line,
                )
            out.append(_vertex_scan(k, raw, pose))
        return out


def _vertex_scan(index: int, raw: RawScan, pose: NDArray[np.float64]) -> Scan:
    """A vertex's scan, placed in the vertex's (the robot's) frame.

    ROBOTLASER1 gives the laser's pose and the robot's; the laser's pose in the robot's frame
    is the mount, whatever estimate either pose was written from.
    """
    assert raw.angle_min is not None and raw.angle_increment is not None
    assert raw.max_range is not None
    laser, robot = raw.pose, raw.robot_pose if raw.robot_pose is not None else raw.pose
    offset = se2.between(robot, laser)
    mount = LaserMount(float(offset[0]), float(offset[1]), float(offset[2]))
    return Scan(
        index=index,
        timestamp=raw.timestamp,
        ranges=raw.ranges,
        angle_min=raw.angle_min,
        angle_increment=raw.angle_increment,
        max_range=raw.max_range,
        odometry=pose,
        line=raw.line,
        mount=None if mount.is_base else mount,
    )


def _id(p: LineParser, i: int) -> int:
    token = p.tokens[i] if i < len(p.tokens) else ""
    if not (token.isdigit() and len(token) <= 9):
        raise p.fail(f"field {i} {quote_token(token)} is not a vertex id")
    return int(token)


def _positive_definite(m: NDArray[np.float64]) -> bool:
    try:
        np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return False
    return True


def read_graph(path: str | Path) -> PoseGraphFile:
    """Reads a g2o 2D or TORO pose graph.

    Raises:
        InputError: The file is missing, not text, or any line is malformed, names a missing
            vertex, or the graph has a vertex no edge names.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such file" if not path.exists() else "not a file")
    reader = _Reader(path)
    try:
        with path.open("r", encoding="utf-8", errors="strict") as f:
            for lineno, text in enumerate(f, start=1):
                tokens = text.split()
                if tokens and not tokens[0].startswith("#"):
                    reader.line(lineno, tokens)
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not a text graph ({exc.reason} at byte {exc.start})") from None
    return reader.graph()


def information_of(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """The information matrix of a covariance, made exactly symmetric."""
    info = np.linalg.inv(np.asarray(covariance, dtype=np.float64))
    return np.asarray(0.5 * (info + info.T), dtype=np.float64)


def write_g2o(
    path: str | Path,
    poses: NDArray[np.float64],
    edges: Sequence[G2oEdge],
    scans: Sequence[Scan] | None = None,
    fixed: int = 0,
) -> None:
    """Writes a g2o 2D graph that stands alone: each vertex followed by its scan.

    Args:
        path: The file (written whole or not at all).
        poses: (V, 3) vertex poses.
        edges: The constraints (vertex indices are the written ids).
        scans: One per vertex, written as ROBOTLASER1 (laser pose = vertex ∘ mount).
        fixed: The vertex written as ``FIX``.
    """
    out = []
    for k, pose in enumerate(np.asarray(poses, dtype=np.float64)):
        out.append(f"VERTEX_SE2 {k} {_num(pose[0])} {_num(pose[1])} {_num(pose[2])}")
        if scans is not None:
            out.append(_robotlaser(scans[k], pose))
    for e in edges:
        info = np.asarray(e.information, dtype=np.float64)
        values = " ".join(_num(info[r, c]) for r, c in _G2O_ORDER)
        z = e.measurement
        out.append(f"EDGE_SE2 {e.a} {e.b} {_num(z[0])} {_num(z[1])} {_num(z[2])} {values}")
    # Last: gtsam's readG2o (4.3) reads no edge after a FIX line.
    out.append(f"FIX {fixed}")
    write_text_atomically(path, "\n".join(out) + "\n")


def _robotlaser(scan: Scan, pose: NDArray[np.float64]) -> str:
    mount = scan.mount.pose if scan.mount is not None else np.zeros(3)
    # No-returns are written as the maximum range: the reader takes them for none again.
    ranges = np.where(scan.valid(), scan.ranges, scan.max_range)
    return format_robotlaser(
        ranges,
        angle_min=scan.angle_min,
        angle_increment=scan.angle_increment,
        max_range=scan.max_range,
        laser_pose=se2.compose(pose, mount),
        robot_pose=pose,
        timestamp=scan.timestamp if math.isfinite(scan.timestamp) else 0.0,
    )


def _num(value: float) -> str:
    return f"{float(value):.9g}"


def graph_log(graph: PoseGraphFile) -> ScanLog:
    """A graph's scans as a log, one per vertex, with the vertices' poses as odometry: what
    ``open_log`` gives for a graph file, so that the studio, ``info`` and ``audit`` read a
    g2o file's scans as they read a CARMEN log's.

    Raises:
        InputError: The graph carries no scans.
    """
    if graph.scans is None:
        raise InputError(
            graph.path,
            "is a pose graph without scans (no ROBOTLASER1 lines): the scans are in the log "
            "or bag its SLAM read",
        )
    return ScanLog(
        path=graph.path,
        format=graph.format,
        scans=list(graph.scans),
        content_hash=graph.content_hash,
        pose_source="odometry",
        message_counts={"VERTEX_SE2": len(graph), "ROBOTLASER1": len(graph.scans)},
    )
