"""Reference labels: did the matcher's estimate land on the reference relative pose?"""

from __future__ import annotations

import math
from dataclasses import dataclass

from numpy.typing import ArrayLike

from vgm_studio.core import se2
from vgm_studio.matching.edges import Label


@dataclass(frozen=True)
class LabelThresholds:
    """With e = reference⁻¹ ∘ estimate: ``success`` when |e_xy| ≤ success_xy and
    |e_θ| ≤ success_theta_deg; ``failure`` when |e_xy| ≥ failure_xy or |e_θ| ≥ failure_theta_deg;
    ``ambiguous`` in between."""

    success_xy: float = 0.10
    success_theta_deg: float = 2.0
    failure_xy: float = 0.30
    failure_theta_deg: float = 5.0


def reference_label(
    reference: ArrayLike, estimate: ArrayLike, thresholds: LabelThresholds | None = None
) -> Label:
    """Labels an estimate against the reference relative pose."""
    t = thresholds or LabelThresholds()
    exy, eth = se2.pose_error(reference, estimate)
    eth_deg = math.degrees(eth)
    if exy <= t.success_xy and eth_deg <= t.success_theta_deg:
        return "success"
    if exy >= t.failure_xy or eth_deg >= t.failure_theta_deg:
        return "failure"
    return "ambiguous"
