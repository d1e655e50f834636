"""Sector cuts: one scan loses one sector, nothing else changes, and training uses them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from tests.test_training_runs import _fit, matched_pairs
from vgm_studio.model.features import PairSample
from vgm_studio.model.fitting import Recipe, Rows
from vgm_studio.model.occlusion import FEWEST_LEFT, NARROWEST, WIDEST, cut_sectors

_RING = 720  # points a half degree apart on a circle round the pair's origin


def _ring_pair() -> PairSample:
    angle = np.linspace(-np.pi, np.pi, _RING, endpoint=False)
    ring = (4.0 * np.c_[np.cos(angle), np.sin(angle)]).astype(np.float32)
    return PairSample(ring, (ring * 1.1).astype(np.float32), 0.6, 0.03)


def test_every_cut_takes_one_arc_of_one_scan_and_leaves_the_rest_as_it_was():
    pair = _ring_pair()
    out = cut_sectors([pair] * 200, 1.0, np.random.default_rng(4))
    which = []
    for cut in out:
        prev_cut, cur_cut = len(cut.prev) < _RING, len(cut.cur) < _RING
        assert prev_cut != cur_cut  # one scan, never both, never neither
        changed, whole = (cut.prev, pair.prev) if prev_cut else (cut.cur, pair.cur)
        kept = cut.cur if prev_cut else cut.prev
        np.testing.assert_array_equal(kept, pair.cur if prev_cut else pair.prev)
        assert (cut.inlier_ratio, cut.residual) == (pair.inlier_ratio, pair.residual)
        # What is left is the scan's own points, in order, less one arc between 60 and 180°.
        left = {tuple(p) for p in changed.tolist()}
        assert left <= {tuple(p) for p in whole.tolist()}
        lost = (_RING - len(changed)) * 2 * np.pi / _RING
        assert NARROWEST - 0.02 <= lost <= WIDEST + 0.02
        angle = np.sort(np.arctan2(changed[:, 1], changed[:, 0]))
        gaps = np.diff(np.r_[angle, angle[0] + 2 * np.pi])
        assert np.sum(gaps > 3 * 2 * np.pi / _RING) == 1  # the points lost are one arc
        which.append(prev_cut)
    assert 0.3 < np.mean(which) < 0.7  # either scan, with even odds


def test_a_share_cuts_that_share_and_none_cuts_nothing():
    pair = _ring_pair()
    half = cut_sectors([pair] * 2000, 0.3, np.random.default_rng(5))
    assert 0.27 < np.mean([c is not pair for c in half]) < 0.33
    assert all(c is pair for c in cut_sectors([pair] * 50, 0.0, np.random.default_rng(5)))
    with pytest.raises(ValueError, match="share"):
        cut_sectors([pair], 1.5, np.random.default_rng(5))


def test_a_scan_seen_through_a_narrow_cone_is_not_cut_to_nothing():
    cone = np.c_[np.linspace(2, 6, 40), np.linspace(-0.1, 0.1, 40)].astype(np.float32)
    pair = PairSample(cone, cone.copy(), 0.6, 0.03)
    out = cut_sectors([pair] * 300, 1.0, np.random.default_rng(6))
    assert min(min(len(c.prev), len(c.cur)) for c in out) >= FEWEST_LEFT
    # A sector that misses the cone leaves every point: those pairs come back whole.
    assert any(len(c.prev) == len(c.cur) == 40 for c in out)


def test_training_reads_the_cut_pairs_and_draws_them_again_the_same():
    samples, labels = matched_pairs(48, seed=2)
    idx = np.arange(48)
    rows = Rows(samples, labels, idx[idx % 4 != 0], idx[idx % 4 == 0])
    recipe = Recipe(epochs=2, epoch_size=64, batch_size=16, patience=9, seed=5)
    plain = _fit(rows, recipe)
    cut = _fit(rows, replace(recipe, occlude=1.0))
    again = _fit(rows, replace(recipe, occlude=1.0))
    for name, weight in cut.state_dict.items():  # the cuts come from the run's seed
        torch.testing.assert_close(again.state_dict[name], weight, rtol=0, atol=0)
    # The cuts reached the network: the same draws and seed end at other weights.
    differ = [
        name
        for name, weight in plain.state_dict.items()
        if weight.is_floating_point() and not torch.equal(cut.state_dict[name], weight)
    ]
    assert differ
