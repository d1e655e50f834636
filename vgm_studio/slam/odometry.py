"""kiss-icp odometry with the log's own odometry as its motion prior.

kiss-icp predicts each frame with a constant-velocity model (``last_pose @ last_delta``). In a
2 m corridor whose walls pin down only one direction, ICP cannot correct a wrong prediction
along the corridor, and at the start of a log (zero velocity) it lags behind: on simulated
corridor loops that alone leaves half the steps centimetres to decimetres off. Wheel
odometry is a far better prediction over one scan, so where the log has it, it replaces the
constant-velocity delta before each frame; ICP then corrects what the wheels got wrong.

Without wheels, a log whose scans are far apart (a corrected log thinned to one scan a metre,
Örebro: steps of 1–3 m and up to 76°) defeats the constant-velocity prediction: ICP only pairs
points within 3σ (0.9 m), so it stays where it predicted and every later step inherits the
error. There, every step is searched again against the previous scan by the branch-and-bound
correlative matcher, which converges from metres and tens of degrees off, and replaces
kiss-icp's where it scores clearly higher. What it cannot mend: along a featureless or
periodic corridor a step a door further scores as well as the right one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from kiss_icp.kiss_icp import KissICP
from numpy.typing import NDArray
from tqdm import tqdm

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.branch_bound import (
    SearchWindow,
    angular_step,
    branch_and_bound,
    thin_points,
)
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.odometry import kiss_config
from vgm_studio.matching.refinement import refine_with
from vgm_studio.matching.registration import as_3d, pose_to_4x4
from vgm_studio.matching.submap import Submap


@dataclass(frozen=True)
class Recovery:
    """How a wheel-less kiss-icp step is searched again.

    Attributes:
        linear: Half-width of the search in x and y around the previous scan, metres: the
            widest loop window (3 m); a log with scans farther apart is not one a scan
            matcher can follow without wheels.
        angular_deg: …in heading, degrees. A 180° scanner turned by more than 90° keeps less
            than half of its view, too little to match, so wider would only add false poses.
        gain: The search's step replaces kiss-icp's only if its correlative score (mean
            likelihood of the scan on the previous one) is this much higher, relative
            (``inf``: never searched).
        step_range: The search turns in steps that move a point at this range by one grid
            cell (Cartographer's rule with a nearer "farthest point"): at a scanner's 30 m a
            90° window takes ~1900 steps, three times as many for little gain, since the
            refinement takes the last tenth of a degree.
    """

    linear: float = 3.0
    angular_deg: float = 90.0
    gain: float = 0.1
    step_range: float = 10.0


def scan_odometry(
    scans: Sequence[Scan],
    config: MatchConfig | None = None,
    progress: bool = True,
    recovery: Recovery | None = None,
) -> NDArray[np.float64]:
    """kiss-icp odometry over scans in order, predicted by the scans' own odometry if any.

    Returns:
        (N, 3) sensor poses (x, y, θ) relative to the first scan.
    """
    config = config or MatchConfig()
    recovery = recovery or Recovery()
    pipeline = KissICP(kiss_config(config))
    wheels = all(s.odometry is not None for s in scans)
    poses = np.zeros((len(scans), 3))
    previous: Scan | None = None
    bar = tqdm(scans, desc="odometry", unit="scan", disable=None if progress else True)
    for i, scan in enumerate(bar):
        if wheels and i > 0:
            delta = se2.between(scans[i - 1].odometry, scan.odometry)  # type: ignore[arg-type]
            pipeline.last_delta = pose_to_4x4(delta)
        pts = scan.points()
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= config.max_range]
        if len(pts) >= 3:
            pipeline.register_frame(as_3d(pts), np.zeros(len(pts)))
            if not wheels and previous is not None and math.isfinite(recovery.gain):
                _recover(pipeline, previous, pts, poses[i - 1], config, recovery)
            previous = scan
        else:
            # Nothing to register: carry the prediction.
            pipeline.last_pose = pipeline.last_pose @ pipeline.last_delta
        poses[i] = se2.from_matrix(pipeline.last_pose)
    return poses


def _recover(
    pipeline: KissICP,
    previous: Scan,
    pts: NDArray[np.float64],
    last: NDArray[np.float64],
    config: MatchConfig,
    recovery: Recovery,
) -> None:
    """Searches kiss-icp's last step again over a wide window, and restarts kiss-icp's local
    map from the two scans if the search found a clearly better step."""
    step = se2.between(last, se2.from_matrix(pipeline.last_pose))
    submap = Submap.from_scans(
        [previous],
        np.zeros((1, 3)),
        max_range=config.max_range,
        normal_neighbors=config.normal_neighbors,
    )
    # Near the sensor a laser puts several points in a cell: one per two cells scores alike
    # for a third less time (the refinement below uses them all).
    coarse = thin_points(pts, 2 * submap.resolution)
    here = branch_and_bound(submap, coarse, step, SearchWindow(0.0, 0.0))
    bar = (1.0 + recovery.gain) * (here.score if here is not None else 0.0)
    if bar >= 1.0:
        return
    # Only poses that beat kiss-icp's clearly are searched: where it is right, branch and
    # bound prunes nearly everything at the coarse levels.
    window = SearchWindow(recovery.linear, math.radians(recovery.angular_deg))
    turn = angular_step(np.array([[recovery.step_range, 0.0]]), submap.resolution)
    # Around standing still, not around kiss-icp's step: once lost, kiss-icp may carry a wrong
    # speed further than any window, but a scan is rarely more than the window from the last.
    hit = branch_and_bound(submap, coarse, np.zeros(3), window, step=turn, min_score=bar)
    if hit is None:
        return
    found = refine_with(submap.target(), pts, hit.pose, config).estimate
    pose = pose_to_4x4(se2.compose(last, found))
    # kiss-icp's map holds this scan where it was lost: start it again from the two scans.
    pipeline.local_map.clear()
    pipeline.local_map.update(pipeline.voxelize(as_3d(submap.points))[1], pose_to_4x4(last))
    pipeline.local_map.update(pipeline.voxelize(as_3d(pts))[1], pose)
    pipeline.last_delta = pose_to_4x4(found)
    pipeline.last_pose = pose
