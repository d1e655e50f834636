"""Typed configuration of the pose graph and its optimiser."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

RobustName = Literal["none", "huber", "gnc"]
ROBUST: tuple[str, ...] = ("none", "huber", "gnc")


@dataclass(frozen=True)
class GraphConfig:
    """The pose graph and its optimiser.

    Attributes:
        robust: ``none`` (plain least squares), ``huber`` (gtsam's Huber kernel on every
            edge) or ``gnc`` (graduated non-convexity with a truncated quadratic; sequential
            edges are known inliers).
        huber_k: Huber threshold, in whitened units (σ).
        min_sigma_xy: Floor on an edge's translational σ, metres: the matcher's covariance
            from residuals alone is millimetres, far more certain than a scan pair is.
        min_sigma_theta_deg: Floor on its rotational σ, degrees.
        odometry_sigma_xy: σ of the odometry fallback that joins keyframes whose sequential
            edge was rejected (a match the validator was only unsure of joins them at the
            narrower ``FrontEndConfig.drift_odometry_sigma_*`` instead), metres per metre
            travelled (plus ``min_sigma_xy``). Wide on
            purpose: the odometry goes in exactly where a scan match disagreed with it, and
            there it is often far off (CSAIL and Belgioioso: 11–47° at such steps). With a
            narrow σ the graph believes it, and the consistency check lets that belief
            veto the right loops that would mend it.
        odometry_sigma_theta_deg: …and its rotational σ, degrees.
        gnc_probability: GNC's inlier threshold as the χ²(3) quantile at this probability:
            an edge whose cost stays above it ends with weight 0.
    """

    robust: RobustName = "none"
    huber_k: float = 1.345
    min_sigma_xy: float = 0.02
    min_sigma_theta_deg: float = 0.5
    odometry_sigma_xy: float = 0.25
    odometry_sigma_theta_deg: float = 10.0
    gnc_probability: float = 0.99
