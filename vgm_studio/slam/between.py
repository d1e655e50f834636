"""Scans between keyframes placed by the keyframes on either side of them.

A map is scored by relations between scans at most a metre or two apart (Kümmerle et al.):
of Intel's 2,984, 11 join two keyframes. Most of a run's relation error therefore lies in
where its scans between keyframes are, and carried there from a keyframe by the odometry
(``pipeline.scan_poses``) they take the odometry's drift over the last metres. Every
``ANCHOR_DISTANCE`` or ``ANCHOR_ANGLE_DEG`` of odometry, a scan between keyframes (an anchor)
is refined onto the keyframe before it and the one after (point to line, from the odometry's
step, as a match's final centimetres are) and placed between the two by its share of the
scans between them; the other scans are carried from the keyframes and anchors around them.
A refinement that does not hold leaves that side to the odometry. On Intel, with the bundled
validator and so the same graph (``BENCHMARKS.md``):

| anchors every | refined scans | relation error | refining, one core |
|---|---|---|---|
| none (odometry carry) | 0 | 0.0238 m, 0.459° | 0 s |
| 0.3 m / 15° | 1,925 | 0.0220 m, 0.392° | 4 s |
| 0.1 m / 5° (chosen) | 5,207 | 0.0197 m, 0.332° | 11 s |
| every scan | 12,135 | 0.0170 m, 0.266° | 33 s |

The refinements are relative poses (a scan in a keyframe's frame), so any keyframe trajectory
(``before`` and ``after``) places the scans by the same ones. Where walls pin nothing along a
corridor a refinement slides: the featureless simulated corridors go from 0.081 to 0.096 m.
No gate on the refinement's move tells those slides from the corrections the GMapping-corrected
logs need, run from their raw odometry (belgioioso: 0.057 m carried, 0.040 refined, 0.054 with
refinements that moved over 5 cm left out).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.progress import track

ANCHOR_DISTANCE = 0.1
ANCHOR_ANGLE_DEG = 5.0

# A refinement holds where it converged with at least this share of the scan's points on the
# keyframe's walls (a local map's neighbour is held so too: ``model.context.Context``).
MIN_INLIERS = 0.5


@dataclass(frozen=True)
class BetweenPlacements:
    """Anchors between keyframes in the frames of the keyframes around them.

    Attributes:
        index: (M,) the anchors' indices in the log.
        before: (M,) the keyframe before each (its position among the keyframes).
        pose_before: (M, 3) the anchor in that keyframe's frame; NaN where it did not hold.
        pose_after: (M, 3) …in the next keyframe's frame; NaN where it did not hold or there is
            none (after the last keyframe).
        share: (M,) how far the anchor lies from the keyframe before towards the one after,
            by scan index.
    """

    index: NDArray[np.int64]
    before: NDArray[np.int64]
    pose_before: NDArray[np.float64]
    pose_after: NDArray[np.float64]
    share: NDArray[np.float64]

    def place(
        self, keyframe_poses: NDArray[np.float64]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """The anchors that hold on either side and where ``keyframe_poses`` put them:
        (indices, (H, 3) poses)."""
        last = len(keyframe_poses) - 1
        p0 = se2.compose(keyframe_poses[self.before], self.pose_before)
        p1 = se2.compose(keyframe_poses[np.minimum(self.before + 1, last)], self.pose_after)
        ok0, ok1 = np.isfinite(p0[:, 0]), np.isfinite(p1[:, 0])
        # Between the two refined poses by the anchor's share (a step of centimetres:
        # scaling its (x, y, θ) is the geodesic to well under a millimetre).
        mixed = se2.compose(p0, se2.between(p0, p1) * self.share[:, None])
        pose = np.where((ok0 & ok1)[:, None], mixed, np.where(ok0[:, None], p0, p1))
        held = ok0 | ok1
        return self.index[held], np.asarray(pose[held], dtype=np.float64)


def place_between(
    scans: Sequence[Scan],
    odometry: NDArray[np.float64],
    keyframes: NDArray[np.int64],
    progress: bool = True,
) -> BetweenPlacements:
    """Refines the anchors between keyframes onto the keyframe before and the one after
    each, from the odometry's step (see the module's docstring)."""
    refine = Refiner(scans, odometry)
    picked = select_keyframes(odometry, ANCHOR_DISTANCE, ANCHOR_ANGLE_DEG)
    index = np.setdiff1d(picked[picked > keyframes[0]], keyframes).astype(np.int64)
    before = np.searchsorted(keyframes, index, side="right") - 1
    after = np.minimum(before + 1, len(keyframes) - 1)
    has_after = keyframes[after] > index
    start, end = keyframes[before], np.where(has_after, keyframes[after], index)
    share = np.where(has_after, (index - start) / np.maximum(end - start, 1), 0.0)
    pose_before = np.full((len(index), 3), np.nan)
    pose_after = np.full((len(index), 3), np.nan)
    rows = track(range(len(index)), "placing scans between keyframes", "scan", enabled=progress)
    for m in rows:
        i = int(index[m])
        pose_before[m] = refine(int(keyframes[before[m]]), i)
        if has_after[m]:
            pose_after[m] = refine(int(keyframes[after[m]]), i)
        refine.done(i)
    return BetweenPlacements(index, before.astype(np.int64), pose_before, pose_after, share)


class Refiner:
    """An anchor refined onto a keyframe from the odometry's step; NaN where it does not hold."""

    def __init__(self, scans: Sequence[Scan], odometry: NDArray[np.float64]) -> None:
        self.scans, self.odometry = scans, odometry
        self._matcher = ScanMatcher()

    def __call__(self, k: int, i: int) -> NDArray[np.float64]:
        guess = se2.between(self.odometry[k], self.odometry[i])
        r = self._matcher.refine(self.scans[k], self.scans[i], guess)
        if r is None or not r.converged or r.inlier_ratio < MIN_INLIERS:
            return np.full(3, np.nan)
        return r.estimate

    def done(self, i: int) -> None:
        """Scan ``i`` is refined no more: its cached points go (an anchor is refined here
        alone)."""
        self._matcher.forget(self.scans[i])
