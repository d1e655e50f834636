"""Pairwise registration with kiss-icp: the points of scan b aligned to a voxel map of scan a."""

from __future__ import annotations

import numpy as np
from kiss_icp.mapping import VoxelHashMap
from kiss_icp.registration import Registration
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.matching.config import MatchConfig


def as_3d(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """kiss-icp works in 3D: planar points get z = 0."""
    return np.column_stack([points, np.zeros(len(points))])


def pose_to_4x4(pose: NDArray[np.float64]) -> NDArray[np.float64]:
    m = np.eye(4)
    m[:2, :2] = se2.to_matrix(pose)[:2, :2]
    m[:2, 3] = pose[:2]
    return m


class KissRegistration:
    """Aligns a source scan to a target scan from an initial guess with kiss-icp."""

    def __init__(self, config: MatchConfig) -> None:
        self._config = config
        self._registration = Registration(
            max_num_iterations=config.max_iterations,
            convergence_criterion=1e-4,
            max_num_threads=1,
        )

    def target_map(self, points: NDArray[np.float64]) -> VoxelHashMap:
        """Builds the voxel map of a target scan; reuse it for every source matched against it."""
        voxel_map = VoxelHashMap(
            voxel_size=self._config.voxel_size,
            max_distance=self._config.max_range,
            max_points_per_voxel=self._config.max_points_per_voxel,
        )
        voxel_map.add_points(as_3d(points))
        return voxel_map

    def align(
        self, source: NDArray[np.float64], target: VoxelHashMap, guess: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Returns the pose of the source scan in the target frame, as (x, y, θ)."""
        sigma = self._config.threshold
        result = self._registration.align_points_to_map(
            points=as_3d(source),
            voxel_map=target,
            initial_guess=pose_to_4x4(guess),
            max_correspondance_distance=3.0 * sigma,
            kernel=sigma,  # as kiss-icp's own pipeline does
        )
        return se2.from_matrix(np.asarray(result))
