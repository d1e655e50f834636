"""What the studio draws for one edge, computed once and cached: arrays ready to send."""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.errors import InputError
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.studio.heatmap import blend, channels_panel
from vgm_studio.studio.minimap import Trajectory, minimap, trajectory
from vgm_studio.vgm.grid import VGMParams, pair_map
from vgm_studio.vgm.render import CUR_BGR, PREV_BGR
from vgm_studio.vgm.spread import spread_pair

PREV_RGB: tuple[int, int, int] = (int(PREV_BGR[2]), int(PREV_BGR[1]), int(PREV_BGR[0]))
CUR_RGB: tuple[int, int, int] = (int(CUR_BGR[2]), int(CUR_BGR[1]), int(CUR_BGR[0]))
REFERENCE_RGB: tuple[int, int, int] = (150, 150, 150)


@dataclass(frozen=True)
class PlacedPair:
    """The pair with the current scan placed by one pose (the estimate or the initial guess)."""

    pose: NDArray[np.float64]
    heatmap_rgb: NDArray[np.uint8]  # (h, w, 3) RGB, row i along +y: the occupied part, spread
    channels_rgb: NDArray[np.uint8]  # the panel's picture of both channels (heatmap.channels_panel)
    cells: NDArray[np.float32]  # (K, 3) centres of the occupied cells, metres, z just below 0
    cell_rgb: NDArray[np.uint8]  # (K, 3) their colours mixed from the spread channels
    raw_rgb: NDArray[np.uint8]  # (K, 3) their colours mixed from the raw channels
    heatmap_centre: tuple[float, float]  # where the crop's centre lies, metres
    cur: NDArray[np.float32]  # (M, 3) current scan in the previous scan's frame
    resolution: float  # metres per heatmap pixel (the VGM's cell size)

    @property
    def heatmap_size(self) -> tuple[float, float]:
        """(width, height) of the crop in metres."""
        h, w = self.heatmap_rgb.shape[:2]
        return w * self.resolution, h * self.resolution


@dataclass(frozen=True)
class EdgeView:
    """Everything drawn for one edge, in the previous scan's frame (metres, z = 0).

    Attributes:
        edge: The edge.
        prev: (N, 3) previous scan points.
        estimate: The pair placed by the match estimate.
        guess: The pair placed by the initial guess.
        reference: The current scan's reference pose and its points there, when known.
        extent: Width of the VGM square, metres.
        minimap: The log's trajectory with both scans marked (RGB), None when the log has
            no poses to draw.
    """

    edge: Edge
    prev: NDArray[np.float32]
    estimate: PlacedPair
    guess: PlacedPair
    reference: tuple[NDArray[np.float64], NDArray[np.float32]] | None
    extent: float
    minimap: NDArray[np.uint8] | None = None


def _xyz(points: NDArray[np.float64]) -> NDArray[np.float32]:
    out = np.zeros((len(points), 3), dtype=np.float32)
    out[:, :2] = points
    return out


def _placed(
    prev: NDArray[np.float64],
    cur: NDArray[np.float64],
    pose: list[float],
    params: VGMParams,
) -> PlacedPair:
    pose_arr = np.asarray(pose, dtype=np.float64)
    vgm = pair_map(
        prev, cur, pose_arr, size=params.size, resolution=params.resolution, sigma=params.sigma
    )
    (r0, r1, c0, c1), centre = _crop(vgm, params.resolution)
    crop = vgm[:, r0:r1, c0:c1]
    half = params.size * params.resolution / 2
    origin = (-half + c0 * params.resolution, -half + r0 * params.resolution)
    moved = se2.transform_points(pose_arr, cur)
    spread = spread_pair(crop, origin, params.resolution, (prev, moved))
    rgb = blend(crop, spread)  # row 0 at the grid's -y edge, as viser draws an image's first row
    cells, cell_rgb = _cells(crop, rgb, centre, params.resolution)
    _, raw_rgb = _cells(crop, blend(crop), centre, params.resolution)
    return PlacedPair(
        pose_arr,
        rgb,
        channels_panel(crop),
        cells,
        cell_rgb,
        raw_rgb,
        centre,
        _xyz(moved),
        params.resolution,
    )


def _cells(
    crop: NDArray[np.float32],
    rgb: NDArray[np.uint8],
    centre: tuple[float, float],
    resolution: float,
) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """The occupied cells as points (centres, colours): drawn as squares one cell wide.

    A software-rendering browser pays for every screen pixel a picture covers; the occupied
    cells are a few percent of the crop, so squares cost a fraction of the picture.
    """
    rows, cols = np.nonzero((crop[0] > 0) | (crop[1] > 0))
    h, w = crop.shape[1:]
    out = np.full((len(rows), 3), -0.01, dtype=np.float32)
    out[:, 0] = centre[0] + (cols + 0.5 - w / 2) * resolution
    out[:, 1] = centre[1] + (rows + 0.5 - h / 2) * resolution
    return out, np.ascontiguousarray(rgb[rows, cols])


def _crop(
    vgm: NDArray[np.float32], resolution: float, margin: int = 10
) -> tuple[tuple[int, int, int, int], tuple[float, float]]:
    """The rows and columns of the occupied cells and a margin, and where their centre lies.

    The browser pays for every screen pixel an image covers, and without a GPU a 20 m square
    under a 10 m scan was most of a click's latency; the empty rest is background anyway.
    """
    occupied = (vgm[0] > 0) | (vgm[1] > 0)
    size = occupied.shape[0]
    if not occupied.any():
        return (0, 1, 0, 1), (0.0, 0.0)
    rows = np.flatnonzero(occupied.any(axis=1))  # rows run along +y in the VGM
    cols = np.flatnonzero(occupied.any(axis=0))
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, size)
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, size)
    half = size / 2
    centre = ((c0 + c1) / 2 - half) * resolution, ((r0 + r1) / 2 - half) * resolution
    return (int(r0), int(r1), int(c0), int(c1)), (float(centre[0]), float(centre[1]))


def make_view(
    edge: Edge, scans: EdgeScans, params: VGMParams, path: Trajectory | None = None
) -> EdgeView:
    """Reads the edge's scans and builds both placements, the reference ghost and the minimap."""
    a, b = scans.scans(edge)
    prev, cur = a.points(), b.points()
    reference = None
    if edge.reference is not None:
        ref = np.asarray(edge.reference, dtype=np.float64)
        reference = (ref, _xyz(se2.transform_points(ref, cur)))
    return EdgeView(
        edge=edge,
        prev=_xyz(prev),
        estimate=_placed(prev, cur, edge.estimate, params),
        guess=_placed(prev, cur, edge.guess, params),
        reference=reference,
        extent=params.size * params.resolution,
        minimap=None if path is None else minimap(path, edge.a, edge.b, PREV_RGB, CUR_RGB),
    )


def pose_marks(
    current: NDArray[np.float64],
    reference: tuple[NDArray[np.float64], NDArray[np.float32]] | None,
) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """Sensor poses as line segments: x axis (heading) red, y axis green; reference grey.

    One batch of segments instead of a mesh per pose: far cheaper to redraw per edge.

    Returns:
        (S, 2, 3) segment end points and (S, 2, 3) colours.
    """
    poses: list[tuple[NDArray[np.float64], float, tuple[int, int, int] | None]] = [
        (np.zeros(3), 0.6, None),
        (current, 0.6, None),
    ]
    if reference is not None:
        poses.append((reference[0], 0.45, REFERENCE_RGB))
    segments, colours = [], []
    for pose, length, colour in poses:
        x, y, theta = (float(v) for v in pose)
        c, s = math.cos(theta), math.sin(theta)
        for (dx, dy), axis_rgb in (((c, s), (230, 40, 40)), ((-s, c), (40, 200, 40))):
            scale = length if axis_rgb[0] > 100 else length / 2
            segments.append([[x, y, 0.03], [x + scale * dx, y + scale * dy, 0.03]])
            colours.append([colour or axis_rgb] * 2)
    return np.asarray(segments, dtype=np.float32), np.asarray(colours, dtype=np.uint8)


class ViewCache:
    """Views of recently shown and upcoming edges; thread-safe, least recently used out."""

    def __init__(self, scans: EdgeScans, params: VGMParams, capacity: int = 128) -> None:
        self._scans = scans
        self._params = params
        self._capacity = capacity
        self._views: OrderedDict[str, EdgeView] = OrderedDict()
        self._paths: dict[tuple[str, str], Trajectory | None] = {}
        self._lock = threading.Lock()
        # Logs are read once, under this lock: two threads must not parse the same log twice.
        self._read_lock = threading.Lock()

    def get(self, edge: Edge) -> EdgeView:
        with self._lock:
            view = self._views.get(edge.edge_id)
            if view is not None:
                self._views.move_to_end(edge.edge_id)
                return view
        with self._read_lock:
            view = make_view(edge, self._scans, self._params, self._trajectory(edge))
        with self._lock:
            self._views[edge.edge_id] = view
            while len(self._views) > self._capacity:
                self._views.popitem(last=False)
        return view

    def get_or_reason(self, edge: Edge) -> tuple[EdgeView | None, str | None]:
        """The edge's view, or None and one line on why its scans cannot be read."""
        try:
            return self.get(edge), None
        except InputError as exc:
            return None, str(exc)
        except (OSError, ValueError) as exc:  # a log that changed under a running studio
            return None, f"{type(exc).__name__} while reading the log of edge {edge.edge_id}"

    def _trajectory(self, edge: Edge) -> Trajectory | None:
        """The minimap's path of the edge's log, drawn once per log (under the read lock)."""
        key = (edge.log_path, edge.log_sha256)
        if key not in self._paths:
            self._paths[key] = trajectory(self._scans.log_for(edge))
        return self._paths[key]
