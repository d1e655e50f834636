"""Place recognition that does not trust the estimate: a Scan Context for 2D lasers.

Scan Context (Kim and Kim, "Scan Context: Egocentric Spatial Descriptor for Place Recognition
within 3D Point Cloud Map", IROS 2018) divides the plane around the sensor into rings (range
bins) and sectors (bearing bins) and keeps one value per cell. Turning the sensor in place only
shifts the sectors, so

* the ring key (one number per ring, summed over sectors) does not change with heading: it goes
  into a k-d tree (scipy's ``cKDTree``) for nearest-neighbour candidates, and
* the column-shift distance (the best over all sector shifts of the mean column dissimilarity)
  compares two places whatever their headings, and the best shift is a yaw guess.

A 2D laser has no heights, so a cell holds whether any end point falls in it (spread a little
along the range to neighbouring rings, so a revisit from a few decimetres away still overlaps).
Many logs have a 180° field of view, so only the sectors in view have points; the distance
counts a sector seen by one scan and not the other as a mismatch, which keeps two half views
that overlap by a few sectors from looking alike.

Nothing here reads a pose: a revisit is found however far the estimate has drifted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class DescriptorConfig:
    """Scan Context settings.

    Attributes:
        rings: Range bins between 0 and ``max_range``.
        sectors: Bearing bins over the full turn; the yaw guess is a multiple of 360°/sectors.
        max_range: Points farther than this are left out, metres.
        min_points: Scans with fewer points in range have no descriptor worth comparing.
        candidates: Nearest ring keys compared by column-shift distance per query.
    """

    rings: int = 30
    sectors: int = 120
    max_range: float = 30.0
    min_points: int = 20
    candidates: int = 25


@dataclass(frozen=True)
class Descriptor:
    """A scan's Scan Context.

    Attributes:
        context: (rings, sectors) cell values, 0..1; columns normalised for the cosine.
        seen: (sectors,) which sectors hold any point.
        ring_key: (rings,) the share of sectors occupied in each ring: heading-invariant.
    """

    context: NDArray[np.float64]
    seen: NDArray[np.bool_]
    ring_key: NDArray[np.float64]


@dataclass(frozen=True)
class PlaceMatch:
    """A keyframe that looks like the query.

    Attributes:
        key: The keyframe's key, as given to ``PlaceIndex.add``.
        distance: Column-shift distance, 0 (same) .. 1 (nothing in common).
        yaw: Heading of the query scan in the keyframe's frame, radians: a guess good to about
            a sector (3° by default), for a matcher's angular window.
    """

    key: int
    distance: float
    yaw: float


def describe(points: NDArray[np.float64], config: DescriptorConfig | None = None) -> Descriptor:
    """The Scan Context of one scan's (N, 2) end points in its sensor frame."""
    cfg = config or DescriptorConfig()
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r = np.hypot(pts[:, 0], pts[:, 1])
    keep = (r < cfg.max_range) & (r > 0)
    ring = np.minimum((r[keep] / cfg.max_range * cfg.rings).astype(np.intp), cfg.rings - 1)
    bearing = np.mod(np.arctan2(pts[keep, 1], pts[keep, 0]), 2 * math.pi)
    sector = np.minimum((bearing / (2 * math.pi) * cfg.sectors).astype(np.intp), cfg.sectors - 1)
    hit = np.zeros((cfg.rings, cfg.sectors), dtype=np.float64)
    hit[ring, sector] = 1.0
    ring_key = hit.mean(axis=1)
    # Half weight to the neighbouring rings: a revisit a little nearer or farther still overlaps.
    soft = hit.copy()
    soft[1:] = np.maximum(soft[1:], 0.5 * hit[:-1])
    soft[:-1] = np.maximum(soft[:-1], 0.5 * hit[1:])
    norms = np.linalg.norm(soft, axis=0)
    seen = norms > 0
    context = np.where(seen, soft / np.where(seen, norms, 1.0), 0.0)
    return Descriptor(context=context, seen=seen, ring_key=ring_key)


def shift_distances(
    query: Descriptor, others: list[Descriptor]
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Column-shift distance from ``query`` to each of ``others``, and the best shift.

    For shift s, query sector j is compared with sector j + s of the other: the distance is
    1 − (sum of the column cosines) / (sectors seen by either), minimised over s. Both sums
    over j are circular cross-correlations, computed for all shifts at once by FFT.
    """
    sectors = query.seen.shape[0]
    if not others:
        return np.zeros(0), np.zeros(0, dtype=np.intp)
    ctx = np.stack([o.context for o in others])  # (C, R, S)
    seen = np.stack([o.seen for o in others]).astype(np.float64)  # (C, S)
    qf = np.conj(np.fft.rfft(query.context, axis=-1))
    cos = np.fft.irfft(np.sum(qf[None] * np.fft.rfft(ctx, axis=-1), axis=1), n=sectors)
    qs = query.seen.astype(np.float64)
    both = np.fft.irfft(np.conj(np.fft.rfft(qs))[None] * np.fft.rfft(seen, axis=-1), n=sectors)
    either = qs.sum() + seen.sum(axis=1, keepdims=True) - np.rint(both)
    dist = 1.0 - cos / np.maximum(either, 1.0)
    best = np.argmin(dist, axis=1)
    return dist[np.arange(len(others)), best], best


class PlaceIndex:
    """Rotation-invariant ring keys in a scipy cKDTree (rebuilt lazily), re-ranked by Scan
    Context's column-shift distance, which also gives a yaw guess."""

    def __init__(self, config: DescriptorConfig | None = None) -> None:
        self.config = config or DescriptorConfig()
        self._keys: list[int] = []
        self._descriptors: list[Descriptor] = []
        self._tree: cKDTree | None = None

    def __len__(self) -> int:
        return len(self._keys)

    def add(self, key: int, points: NDArray[np.float64]) -> None:
        """Adds one keyframe's scan (its (N, 2) end points in its sensor frame) under ``key``.

        Scans with fewer than ``min_points`` points in range are not added.
        """
        d = describe(points, self.config)
        if int(d.seen.sum()) == 0 or _count(points, self.config) < self.config.min_points:
            return
        self._keys.append(int(key))
        self._descriptors.append(d)
        self._tree = None

    def query(
        self, points: NDArray[np.float64], k: int = 3, max_key: int | None = None
    ) -> list[PlaceMatch]:
        """The ``k`` keyframes most like the scan, best first, only keys ≤ ``max_key``."""
        if not self._keys or _count(points, self.config) < self.config.min_points:
            return []
        q = describe(points, self.config)
        rows = self._nearest(q, max(k, self.config.candidates), max_key)
        if not rows:
            return []
        dist, shift = shift_distances(q, [self._descriptors[i] for i in rows])
        order = np.argsort(dist, kind="stable")[:k]
        step = 2 * math.pi / self.config.sectors
        return [
            PlaceMatch(
                key=self._keys[rows[i]],
                distance=float(dist[i]),
                yaw=float(np.pi - np.mod(np.pi - shift[i] * step, 2 * np.pi)),
            )
            for i in order
        ]

    def _nearest(self, q: Descriptor, count: int, max_key: int | None) -> list[int]:
        """Rows of the ``count`` nearest ring keys among keys ≤ ``max_key``."""
        if self._tree is None:
            self._tree = cKDTree(np.stack([d.ring_key for d in self._descriptors]))
        keys = np.asarray(self._keys)
        allowed = int(np.sum(keys <= max_key)) if max_key is not None else len(keys)
        want = min(count, allowed)
        ask = want
        while True:
            _, idx = self._tree.query(q.ring_key, k=min(ask, len(keys)))
            rows = [int(i) for i in np.atleast_1d(idx) if max_key is None or keys[i] <= max_key]
            if len(rows) >= want or ask >= len(keys):
                return rows[:want]
            ask *= 4


def _count(points: NDArray[np.float64], config: DescriptorConfig) -> int:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return int(np.sum(np.hypot(pts[:, 0], pts[:, 1]) < config.max_range))
