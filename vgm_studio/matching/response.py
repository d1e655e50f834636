"""How far a match could slide: the covariance of the correlative score's surface around it.

A refinement's covariance, σ̂²·(JᵀJ)⁻¹, is the curvature of its residuals at the pose it
settled on: millimetres wherever a few points pin the pose, even where another pose half a metre
along a corridor scores as well or better. The score's own surface says so. Olson ("Real-Time
Correlative Scan Matching", ICRA 2009, section III.D) reads the surface as a likelihood and
takes its second moment; here the likelihood of a pose is exp(ΔS / τ), ΔS its score below the
best one counted in whole points (a point on an end point scores 1) and τ how many points'
worth of score make a pose e times less likely. Olson's τ is 1, the points independent; a
scan's neighbouring points see the same wall and are not, so τ is larger.

The surface is sampled on the submap's cells around the pose, in translation at its heading
and in heading at its translation: the cross terms are left out, and the window's edge bounds
the spread (a flat corridor reads as the window's own width, not as infinite).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.matching.branch_bound import SearchWindow, surface
from vgm_studio.matching.submap import PEAK, Submap


@dataclass(frozen=True)
class Response:
    """The score's surface around a match.

    Attributes:
        covariance: (x, y, θ) covariance in the submap's frame; None where no point falls on
            the grid near the pose.
        score: The score at the pose itself, as ``score_at`` gives it (the surface's centre).
    """

    covariance: NDArray[np.float64] | None
    score: float


def response_surface(
    submap: Submap,
    points: NDArray[np.float64],
    pose: NDArray[np.float64],
    linear: float,
    angular: float,
    temperature: float,
) -> Response:
    """The covariance of the score's surface around ``pose``, and the score at ``pose``.

    Args:
        submap: The grid the scan was matched on.
        points: The scan's points, in its own frame.
        pose: The match: the scan's pose in the submap's frame.
        linear: Half-width of the translations sampled, metres.
        angular: Half-width of the headings sampled, radians.
        temperature: τ, in points (see the module's docstring).
    """
    if len(points) == 0:
        return Response(None, 0.0)
    pose = np.asarray(pose, dtype=np.float64)
    _, shifts, plane = surface(submap, points, pose, SearchWindow(linear, 0.0))
    if plane.max() <= 0:
        return Response(None, 0.0)
    # The plane's centre is the pose itself, scored as ``score_at`` scores it.
    centre = float(plane[0, len(shifts) // 2, len(shifts) // 2]) / (PEAK * len(points))
    gx, gy = (g.ravel() for g in np.meshgrid(shifts, shifts, indexing="ij"))
    cov = np.zeros((3, 3))
    cov[:2, :2] = _moment(np.column_stack([gx, gy]), plane.ravel(), temperature)
    headings, _, line = surface(submap, points, pose, SearchWindow(0.0, angular))
    cov[2, 2] = _moment((headings - pose[2])[:, None], line.ravel(), temperature)[0, 0]
    return Response(cov, centre)


def _moment(
    samples: NDArray[np.float64], scores: NDArray[np.int32], temperature: float
) -> NDArray[np.float64]:
    """The second moment of ``samples`` about their weighted mean, each weighted by
    exp(ΔS / τ)."""
    gap = (scores.astype(np.float64) - float(scores.max())) / (PEAK * max(temperature, 1e-9))
    weight = np.exp(gap)
    weight /= weight.sum()
    mean = weight @ samples
    centred = samples - mean
    out: NDArray[np.float64] = centred.T @ (centred * weight[:, None])
    return out


def score_at(submap: Submap, points: NDArray[np.float64], pose: NDArray[np.float64]) -> float:
    """The mean grid value under the scan's points at ``pose`` (0..1), as the search scores
    its grid poses."""
    if len(points) == 0:
        return 0.0
    _, _, one = surface(submap, points, np.asarray(pose, dtype=np.float64), SearchWindow(0, 0))
    return float(one[0, 0, 0]) / (PEAK * len(points))
