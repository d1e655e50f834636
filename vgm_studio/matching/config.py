"""Typed configuration of the matching stage."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MatchConfig:
    """Scan matcher settings: kiss-icp registration, then a 2D point-to-line refinement.

    Attributes:
        max_range: Readings farther than this are left out of matching, in metres.
        voxel_size: kiss-icp voxel edge for the target map, in metres.
        max_points_per_voxel: kiss-icp points kept per voxel.
        threshold: kiss-icp's σ: correspondences up to 3σ, robust kernel σ, in metres.
        max_iterations: kiss-icp Gauss-Newton iterations at most.
        refine: Run the 2D point-to-line refinement after kiss-icp (kiss-icp is point-to-point
            and leaves a ~2 cm error floor on 2D scans).
        refine_iterations: Refinement iterations at most.
        refine_distance: Correspondences farther than this are dropped by the refinement.
        inlier_distance: A point whose point-to-line residual is below this is an inlier.
        normal_neighbors: Neighbours used to fit each target point's local line.
        degeneracy: The refinement leaves directions whose curvature is below this share of
            the largest where kiss-icp put them (along a featureless corridor, say).
    """

    max_range: float = 30.0
    voxel_size: float = 0.1
    max_points_per_voxel: int = 20
    threshold: float = 0.3
    max_iterations: int = 100
    refine: bool = True
    refine_iterations: int = 30
    refine_distance: float = 0.3
    inlier_distance: float = 0.05
    normal_neighbors: int = 6
    degeneracy: float = 0.005
