"""Choosing a p(success) cut by validation precision, and keeping the curve in checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vgm_studio.errors import InputError
from vgm_studio.model.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from vgm_studio.model.operating import (
    PrecisionCurve,
    precision_curve,
    threshold_for_precision,
)
from vgm_studio.model.registry import build_network
from vgm_studio.model.validator import Validator

# Worked by hand. Distinct cuts 0.3, 0.6, 0.8, 0.9 (0.8 and 0.3 are ties):
#   p ≥ 0.3: all six, 4 successes      → precision 4/6, recall 4/4
#   p ≥ 0.6: 0.9 0.8 0.8 0.6, 3 succ.  → precision 3/4, recall 3/4
#   p ≥ 0.8: 0.9 0.8 0.8, 2 succ.      → precision 2/3, recall 2/4
#   p ≥ 0.9: 0.9, 1 succ.              → precision 1/1, recall 1/4
LABELS = [True, False, True, True, False, True]
PROBS = [0.9, 0.8, 0.8, 0.6, 0.3, 0.3]


def test_curve_matches_the_hand_computed_one_ties_sharing_a_cut():
    curve = precision_curve(LABELS, PROBS)
    assert curve.thresholds == [0.3, 0.6, 0.8, 0.9]
    np.testing.assert_allclose(curve.precision, [4 / 6, 3 / 4, 2 / 3, 1.0])
    np.testing.assert_allclose(curve.recall, [1.0, 3 / 4, 2 / 4, 1 / 4])


@pytest.mark.parametrize(
    ("precision", "cut"),
    [(0.5, 0.3), (4 / 6, 0.3), (0.7, 0.6), (0.75, 0.6), (0.76, 0.9), (1.0, 0.9)],
)
def test_lowest_cut_reaching_the_precision(precision, cut):
    # 0.76: the cut at 0.8 (2/3) is above 0.6 but below 0.76, so only 0.9 reaches it.
    assert threshold_for_precision(precision_curve(LABELS, PROBS), precision) == cut


def test_no_cut_reaches_the_precision():
    curve = precision_curve([False, True, False], [0.9, 0.2, 0.2])
    assert curve.precision == [1 / 3, 0.0]
    assert threshold_for_precision(curve, 0.5) is None


def _checkpoint(curve: PrecisionCurve | None) -> Checkpoint:
    torch.manual_seed(0)
    net, hyper = build_network("vgmnet", {})
    return Checkpoint("vgmnet", hyper=hyper, state_dict=net.state_dict(), curve=curve)


def test_curve_survives_save_and_load_and_chooses_the_cut(tmp_path):
    path = tmp_path / "with.pt"
    save_checkpoint(path, _checkpoint(precision_curve(LABELS, PROBS)))
    assert load_checkpoint(path).curve == precision_curve(LABELS, PROBS)
    validator = Validator.load(path, device="cpu")
    assert validator.threshold_at_precision(0.75) == 0.6
    with pytest.raises(InputError) as caught:
        validator.threshold_at_precision(1.5)
    assert "no threshold reaches validation precision 1.5 (best 1.0000)" in str(caught.value)


def test_checkpoint_without_curve_loads_and_refuses_loop_precision_in_one_line(tmp_path):
    path = tmp_path / "old.pt"
    content = _checkpoint(None).to_dict()
    assert "curve" not in content  # as written before curves were kept
    torch.save(content, path)
    validator = Validator.load(path, device="cpu")
    assert validator.checkpoint.curve is None
    with pytest.raises(InputError) as caught:
        validator.threshold_at_precision(0.99)
    line = str(caught.value)
    assert "\n" not in line and str(path) in line and "no validation precision curve" in line
