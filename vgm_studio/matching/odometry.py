"""LiDAR odometry over consecutive scans with kiss-icp's own pipeline."""

from __future__ import annotations

import math
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


class KissOdometry(KissICP):  # type: ignore[misc]  # kiss-icp ships no types
    """kiss-icp's pipeline whose local map drops far points once the sensor has moved.

    kiss-icp walks its whole voxel map after every frame to drop the voxels beyond
    ``max_range``. A 2D scan adds only a few hundred points, so over a building's map that walk
    costs more than the frame's own matching and adding (Intel: 4.1 of 12.2 s of odometry).
    A voxel only gets farther than ``max_range`` by the sensor moving away from it, so the walk
    is made when the sensor is ``sweep`` metres from where the last one was made: the map
    keeps points up to ``max_range + sweep`` instead of ``max_range``, which at 30 m changes
    nothing a 0.9 m correspondence gate can see.

    ``max_slide``: where the prediction is the wheels' step, ICP may turn it as it likes but
    not move it further than this, metres (``slam.odometry.scan_odometry`` says why); beyond
    it the prediction's position stands, turned as ICP turned it (0: always).
    """

    last_pose: NDArray[np.float64]
    last_delta: NDArray[np.float64]

    def __init__(self, config: KISSConfig, sweep: float = 0.5, max_slide: float = math.inf) -> None:
        super().__init__(config)
        self.sweep = sweep
        self.max_slide = max_slide
        self._swept: NDArray[np.float64] | None = None

    def register_frame(
        self, frame: NDArray[np.float64], timestamps: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """kiss-icp's ``register_frame``, its map updated as the class says."""
        frame = self.preprocessor.preprocess(frame, timestamps, self.last_delta)
        source, frame_downsample = self.voxelize(frame)
        sigma = self.adaptive_threshold.get_threshold()
        initial_guess = self.last_pose @ self.last_delta
        new_pose = self.registration.align_points_to_map(
            points=source,
            voxel_map=self.local_map,
            initial_guess=initial_guess,
            max_correspondance_distance=3 * sigma,
            kernel=sigma,
        )
        correction = np.linalg.inv(initial_guess) @ new_pose
        if np.hypot(correction[0, 3], correction[1, 3]) > self.max_slide:
            correction[:3, 3] = 0.0  # the turn about the sensor kept, the slide dropped
            new_pose = initial_guess @ correction
        self.adaptive_threshold.update_model_deviation(correction)
        rotation, origin = new_pose[:3, :3], new_pose[:3, 3]
        self.local_map.add_points(frame_downsample @ rotation.T + origin)
        if self._swept is None or np.linalg.norm(origin - self._swept) >= self.sweep:
            self.local_map.remove_far_away_points(origin)
            self._swept = origin.copy()
        self.last_delta = np.linalg.inv(self.last_pose) @ new_pose
        self.last_pose = new_pose
        return frame, source


def lidar_odometry(
    scans: Sequence[Scan], config: MatchConfig | None = None, progress: bool = True
) -> NDArray[np.float64]:
    """Runs kiss-icp odometry over scans in order.

    Returns:
        (N, 3) sensor poses (x, y, θ) relative to the first scan.
    """
    pipeline = KissOdometry(kiss_config(config or MatchConfig()))
    poses = np.zeros((len(scans), 3))
    for i, scan in enumerate(track(scans, "odometry", "scan", enabled=progress)):
        pts = scan.points()
        if len(pts) >= 3:
            pipeline.register_frame(as_3d(pts), np.zeros(len(pts)))
        poses[i] = se2.from_matrix(pipeline.last_pose)
    return poses
