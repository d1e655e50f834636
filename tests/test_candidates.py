"""Candidate edges on the bundled demo log: pairs, guesses, references, labels, ids."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.datasets.reference import with_reference
from vgm_studio.datasets.relations import match_relations, read_relations
from vgm_studio.matching.candidates import (
    CandidateConfig,
    loop_pairs,
    make_candidates,
    select_keyframes,
)
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.reference_labels import reference_label

DEMO = Path(__file__).resolve().parents[1] / "datasets" / "demo-seed0.log"


@pytest.fixture(scope="module")
def demo():
    return open_log(DEMO)


def test_keyframes_by_distance_and_angle():
    poses = np.array(
        [[0, 0, 0], [0.2, 0, 0], [0.45, 0, 0], [0.6, 0, 0], [0.6, 0, 0.3], [0.6, 0, 0.35]]
    )
    np.testing.assert_array_equal(select_keyframes(poses, 0.4, 15.0), [0, 2, 4])
    np.testing.assert_array_equal(select_keyframes(poses, 0.0, 0.0), np.arange(6))


def test_loop_pairs_respect_every_limit(demo):
    ref = demo.reference_poses()
    config = CandidateConfig(max_loops=10**6)
    pairs = loop_pairs(ref, config)
    a, b = pairs[:, 0], pairs[:, 1]
    assert len(pairs) > 1000
    assert np.all(b - a >= 50)
    assert np.all(np.hypot(*(ref[b, :2] - ref[a, :2]).T) <= 3.0)
    assert np.all(np.abs(se2.wrap_angle(ref[b, 2] - ref[a, 2])) <= math.radians(45))
    # Nothing within the limits is left out.
    d = np.hypot(*(ref[:, None, :2] - ref[None, :, :2]).transpose(2, 0, 1))
    dt = np.abs(se2.wrap_angle(ref[:, None, 2] - ref[None, :, 2]))
    gap = np.arange(len(ref))[None, :] - np.arange(len(ref))[:, None]
    assert len(pairs) == int(((d <= 3) & (dt <= math.radians(45)) & (gap >= 50)).sum())

    sampled = loop_pairs(ref, CandidateConfig(max_loops=100, seed=4))
    again = loop_pairs(ref, CandidateConfig(max_loops=100, seed=4))
    other = loop_pairs(ref, CandidateConfig(max_loops=100, seed=5))
    assert len(sampled) == 100 and np.array_equal(sampled, again)
    assert not np.array_equal(sampled, other)
    assert {tuple(p) for p in sampled} <= {tuple(p) for p in pairs}


def test_make_candidates_protocol(demo):
    config = CandidateConfig(max_loops=150, seed=1)
    edges = make_candidates(demo, ScanMatcher(), config, progress=False)
    seq = [e for e in edges if e.kind == "sequential"]
    loops = [e for e in edges if e.kind == "loop"]
    assert len(seq) == len(demo) - 1 and len(loops) == 150
    ref = demo.reference_poses()
    odo = demo.odometry_poses()
    noise = []
    for e in loops:
        np.testing.assert_allclose(e.reference, se2.between(ref[e.a], ref[e.b]), atol=1e-12)
        noise.append(se2.wrap_angle(np.subtract(e.guess, e.reference)))
        assert e.label == reference_label(e.reference, e.estimate)
    noise = np.array(noise)
    # Guess noise is Gaussian with σ = 0.3 m in x, y and 5° in θ.
    assert 0.22 < noise[:, 0].std() < 0.38 and 0.22 < noise[:, 1].std() < 0.38
    assert 3.5 < math.degrees(noise[:, 2].std()) < 6.5
    np.testing.assert_allclose(seq[0].guess, se2.between(odo[0], odo[1]), atol=1e-12)
    labels = {e.label for e in loops}
    assert {"success", "failure"} <= labels
    assert edges[0].params["candidates"]["seed"] == 1
    again = make_candidates(demo, ScanMatcher(), config, progress=False)
    assert [e.edge_id for e in again] == [e.edge_id for e in edges]
    assert len({e.edge_id for e in edges}) == len(edges)


def test_reference_from_second_log_and_relations(demo, tmp_path):
    # A raw copy without TRUEPOS has no reference; the demo log serves as its reference.
    raw = tmp_path / "raw.log"
    raw.write_text("".join(line for line in DEMO.open() if not line.startswith("TRUEPOS")))
    raw_log = open_log(raw)
    assert not raw_log.has_reference
    joined = with_reference(raw_log, demo)
    np.testing.assert_allclose(joined.reference_poses(), demo.reference_poses())

    ref = demo.reference_poses()
    stamps = demo.timestamps
    rel = tmp_path / "demo.relations"
    rel.write_text(
        "".join(
            f"{stamps[a]:.6f} {stamps[b]:.6f} {p[0]:.6f} {p[1]:.6f} 0 0 0 {p[2]:.6f}\n"
            for a, b in [(10, 80), (20, 200), (5, 6)]
            for p in [se2.between(ref[a], ref[b])]
        )
    )
    matched, missed = match_relations(read_relations(rel), raw_log.timestamps)
    assert missed == 0
    edges = make_candidates(
        raw_log, ScanMatcher(), CandidateConfig(sequential=False), relations=matched, progress=False
    )
    assert [(e.a, e.b) for e in edges] == [(10, 80), (20, 200), (5, 6)]
    for e in edges:
        np.testing.assert_allclose(e.reference, se2.between(ref[e.a], ref[e.b]), atol=2e-6)
        assert e.label is not None


def test_log_without_reference_uses_odometry(demo, tmp_path):
    raw = tmp_path / "raw.log"
    raw.write_text("".join(line for line in DEMO.open() if not line.startswith("TRUEPOS")))
    edges = make_candidates(
        open_log(raw), ScanMatcher(), CandidateConfig(max_loops=20), progress=False
    )
    loops = [e for e in edges if e.kind == "loop"]
    assert loops and all(e.label is None and e.reference is None for e in loops)
    assert edges[-1].params["loop_source"] == "odometry"
