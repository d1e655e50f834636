"""Reference labels checked against the scans: a failure the scans themselves contradict is
ambiguous, not a failure (corrected logs hold references torn ~10° at some revisits)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan, ScanLog
from vgm_studio.matching.candidates import CandidateConfig, make_candidates
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.reference_labels import LabelThresholds, contradicts_reference
from vgm_studio.simulation.raycast import beam_angles, cast

# A room with an alcove and a pillar-like box: every direction of a match is fixed.
WALLS = np.array(
    [
        (-4.0, -3.0, 6.0, -3.0),
        (6.0, -3.0, 6.0, 1.0),
        (6.0, 1.0, 4.5, 1.0),
        (4.5, 1.0, 4.5, 3.0),
        (4.5, 3.0, -4.0, 3.0),
        (-4.0, 3.0, -4.0, -3.0),
        (1.0, -1.0, 2.0, -1.0),
        (2.0, -1.0, 2.0, 0.0),
        (2.0, 0.0, 1.0, 0.0),
        (1.0, 0.0, 1.0, -1.0),
    ]
)
TRUTH = (np.array([-2.0, 0.5, 0.0]), np.array([-1.4, 0.7, 0.25]))


def _scan(index: int, pose: np.ndarray, reference: np.ndarray) -> Scan:
    amin, inc = beam_angles(361, 360.0)
    angles = pose[2] + amin + inc * np.arange(361)
    ranges = cast(pose[:2], angles, WALLS, 30.0).astype(np.float32)
    return Scan(index, float(index), ranges, amin, inc, 30.0, reference=reference)


def _edges(tmp_path: Path, torn_deg: float, thresholds: LabelThresholds):
    """Two scans of one room whose reference turns the second ``torn_deg`` off the truth."""
    torn = TRUTH[1] + np.array([0.0, 0.0, math.radians(torn_deg)])
    scans = [_scan(0, TRUTH[0], TRUTH[0]), _scan(1, TRUTH[1], torn)]
    log = ScanLog(tmp_path / "room.log", "carmen", scans, "h")
    config = CandidateConfig(sequential=False, min_gap=1, noise_xy=0.05, noise_theta_deg=1.0)
    return make_candidates(log, ScanMatcher(), config, thresholds, progress=False)


def test_a_reference_the_scans_contradict_is_ambiguous_not_a_failure(tmp_path):
    (edge,) = _edges(tmp_path, 10.0, LabelThresholds())
    # The matcher found the true pose; the reference is 10° off it.
    true_b_in_a = se2.between(*TRUTH)
    assert se2.pose_error(true_b_in_a, edge.estimate)[0] < 0.02
    assert edge.label == "ambiguous"
    check = edge.match["reference_check"]
    assert check["contradicted"] is True
    assert check["inlier_ratio_from_reference"] > check["inlier_ratio_at_reference"]
    # Without the check the same edge is a failure, as the reference alone says.
    (plain,) = _edges(tmp_path, 10.0, LabelThresholds(check_reference=False))
    assert plain.label == "failure" and "reference_check" not in plain.match


def test_a_true_reference_labels_as_before(tmp_path):
    (edge,) = _edges(tmp_path, 0.0, LabelThresholds())
    assert edge.label == "success" and "reference_check" not in edge.match


def test_only_a_rest_on_the_estimate_that_agrees_better_contradicts():
    estimate = [1.0, 0.0, 0.2]
    # The matcher started at the reference rests on the estimate and agrees better there.
    assert contradicts_reference(estimate, [1.02, 0.01, 0.21], 0.2, 0.6)
    # ... agreeing no better: the scans do not prefer the estimate.
    assert not contradicts_reference(estimate, [1.02, 0.01, 0.21], 0.6, 0.6)
    # ... resting elsewhere (past the success tolerance, in x or in θ): no contradiction.
    assert not contradicts_reference(estimate, [1.2, 0.0, 0.2], 0.2, 0.6)
    assert not contradicts_reference(estimate, [1.0, 0.0, 0.2 + math.radians(3)], 0.2, 0.6)
