"""kiss-icp odometry with the log's own odometry as its motion prior.

kiss-icp predicts each frame with a constant-velocity model (``last_pose @ last_delta``). In a
2 m corridor whose walls pin down only one direction, ICP cannot correct a wrong prediction
along the corridor, and at the start of a log (zero velocity) it lags behind: on simulated
corridor loops that alone leaves half the steps centimetres to decimetres off. Wheel
odometry is a far better prediction over one scan, so where the log has it, it replaces the
constant-velocity delta before each frame; ICP then corrects what the wheels got wrong.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from kiss_icp.kiss_icp import KissICP
from numpy.typing import NDArray
from tqdm import tqdm

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.odometry import kiss_config
from vgm_studio.matching.registration import as_3d, pose_to_4x4


def scan_odometry(
    scans: Sequence[Scan], config: MatchConfig | None = None, progress: bool = True
) -> NDArray[np.float64]:
    """kiss-icp odometry over scans in order, predicted by the scans' own odometry if any.

    Returns:
        (N, 3) sensor poses (x, y, θ) relative to the first scan.
    """
    config = config or MatchConfig()
    pipeline = KissICP(kiss_config(config))
    wheels = all(s.odometry is not None for s in scans)
    poses = np.zeros((len(scans), 3))
    bar = tqdm(scans, desc="odometry", unit="scan", disable=None if progress else True)
    for i, scan in enumerate(bar):
        if wheels and i > 0:
            delta = se2.between(scans[i - 1].odometry, scan.odometry)  # type: ignore[arg-type]
            pipeline.last_delta = pose_to_4x4(delta)
        pts = scan.points()
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= config.max_range]
        if len(pts) >= 3:
            pipeline.register_frame(as_3d(pts), np.zeros(len(pts)))
        else:
            # Nothing to register: carry the prediction.
            pipeline.last_pose = pipeline.last_pose @ pipeline.last_delta
        poses[i] = se2.from_matrix(pipeline.last_pose)
    return poses
