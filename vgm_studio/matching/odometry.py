"""LiDAR odometry over consecutive scans with kiss-icp's own pipeline."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.kiss_icp import KissICP
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.registration import as_3d
from vgm_studio.progress import track


def kiss_config(config: MatchConfig) -> KISSConfig:
    """kiss-icp settings for indoor 2D scans (its defaults are tuned for outdoor 3D LiDAR)."""
    kiss = KISSConfig()
    kiss.data.max_range = config.max_range
    kiss.data.min_range = 0.0
    kiss.data.deskew = False
    kiss.mapping.voxel_size = config.voxel_size
    kiss.mapping.max_points_per_voxel = config.max_points_per_voxel
    kiss.adaptive_threshold.fixed_threshold = config.threshold
    kiss.registration.max_num_threads = 1
    return kiss


def lidar_odometry(
    scans: Sequence[Scan], config: MatchConfig | None = None, progress: bool = True
) -> NDArray[np.float64]:
    """Runs kiss-icp odometry over scans in order.

    Returns:
        (N, 3) sensor poses (x, y, θ) relative to the first scan.
    """
    pipeline = KissICP(kiss_config(config or MatchConfig()))
    poses = np.zeros((len(scans), 3))
    for i, scan in enumerate(track(scans, "odometry", "scan", enabled=progress)):
        pts = scan.points()
        if len(pts) >= 3:
            pipeline.register_frame(as_3d(pts), np.zeros(len(pts)))
        poses[i] = se2.from_matrix(pipeline.last_pose)
    return poses
