"""The surfaces a scan saw: its end points, and the stretch between neighbouring beams that
hit one surface.

Why a correlative search needs them: a grid of end points alone is dense near the sensor and
sparse far from it, most of all along a wall seen at a grazing angle (one beam a degree, a
wall 1 m to the side: 6 m ahead its points lie 0.6 m apart). Scored on such a grid, a scan
fits best where its own dense near points fall on the target's dense near points: along a
corridor, short of the true step, and the shorter the further apart the scans. Örebro, whose
scans lie 1–4 m apart with no wheel odometry: two 2.0–2.1 m steps scored 0.52–0.53 at the
truth against 0.54–0.56 a metre and more short of it; drawn in, 0.74–0.78 against 0.59–0.66.
With the walls whole, a pose scores by how much of the scan lies on the target's surfaces,
not by how densely the target sampled them. Only the wheel-less odometry's search between
single scans draws them (``Submap.from_scans(surfaces=True)``; why not the submaps of
several keyframes: see there).

Which neighbours saw one surface: the adaptive breakpoint detector (G. A. Borges and M.-J.
Aldon, "Line extraction in 2D range images for mobile robotics", J. Intelligent and Robotic
Systems 40, 2004): on a surface seen at more than λ from grazing, neighbouring end points lie
at most r·sin Δφ / sin(λ − Δφ) + 3σ_r apart; further apart, the beams passed an edge between
them, and the gap is left open.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vgm_studio.datasets.scans import Scan

# Borges & Aldon's values: surfaces seen within 10° of grazing are left as points, and a
# laser's range noise of 1 cm.
GRAZING_DEG = 10.0
RANGE_SIGMA = 0.01


def stretch_points(
    scan: Scan,
    max_range: float,
    spacing: float,
    grazing_deg: float = GRAZING_DEG,
) -> NDArray[np.float64]:
    """Points every ``spacing`` metres or closer between neighbouring beams within
    ``max_range`` that hit one surface, in the scan's base frame; the end points themselves
    are not among them.

    Args:
        scan: The scan.
        max_range: Readings farther than this are left out, with the stretches to them.
        spacing: Greatest distance between the points drawn along a stretch, metres (half a
            grid cell marks nearly every cell a stretch crosses; the likelihood's blur covers
            the corners it clips).
        grazing_deg: λ: surfaces seen within this angle of grazing are not joined; nor is
            anything by a scanner whose beams lie more than λ/2 apart.

    Returns:
        (N, 2) points, in beam order.
    """
    keep = scan.valid()
    # No-returns (inf, NaN) at the sensor: they are never joined, and stay finite.
    ranges = np.where(keep, scan.ranges, 0.0).astype(np.float64)
    angles = scan.angles()
    ends = np.stack([ranges * np.cos(angles), ranges * np.sin(angles)], axis=1)
    if scan.mount is not None:
        ends = scan.mount.place(ends)
    # Cut where ``Submap.from_scans`` cuts the end points: by distance from the base.
    keep &= np.hypot(ends[:, 0], ends[:, 1]) <= max_range
    step = abs(scan.angle_increment)
    lam = math.radians(grazing_deg)
    gap = np.hypot(*(ends[1:] - ends[:-1]).T)
    if step <= 0 or step > lam / 2:
        # The detector's bound grows without limit as the beam step nears λ: a scanner that
        # coarse would have every edge joined, so nothing is.
        joined = np.zeros(len(gap), dtype=bool)
    else:
        near = np.minimum(ranges[:-1], ranges[1:])
        widest = near * math.sin(step) / math.sin(lam - step) + 3.0 * RANGE_SIGMA
        joined = keep[:-1] & keep[1:] & (gap <= widest) & (gap > spacing)
    first = np.flatnonzero(joined)
    counts = np.ceil(gap[first] / spacing).astype(np.intp) - 1
    which = np.repeat(first, counts)
    # Fractions 1/n … (n-1)/n along each stretch, n = counts + 1.
    starts = np.cumsum(counts) - counts
    k = np.arange(len(which)) - np.repeat(starts, counts) + 1
    t = (k / np.repeat(counts + 1, counts))[:, None]
    between: NDArray[np.float64] = ends[which] + t * (ends[which + 1] - ends[which])
    return between
