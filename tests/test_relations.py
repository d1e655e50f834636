"""Freiburg relations files: parsing, errors, matching to scans by timestamp."""

from __future__ import annotations

import numpy as np
import pytest

from vgm_studio.datasets import open_log
from vgm_studio.datasets.relations import looks_like_relations, match_relations, read_relations
from vgm_studio.errors import InputError


def test_parse_and_match(tmp_path):
    path = tmp_path / "x.relations"
    path.write_text("10.0 12.0 1 2 0 0 0 0.5\n\n12.0 13.5 -1 0 0 0 0 -0.1\n99 100 0 0 0 0 0 0\n")
    rel = read_relations(path)
    assert len(rel) == 3 and rel[0].line == 1 and rel[1].line == 3
    np.testing.assert_allclose(rel[0].pose, [1, 2, 0.5])
    matched, missed = match_relations(rel, np.array([13.5, 10.0, 12.0002]), tolerance=1e-3)
    assert missed == 1
    assert [(m.a, m.b) for m in matched] == [(1, 2), (2, 0)]
    assert looks_like_relations(path)


def test_malformed_relations(tmp_path):
    path = tmp_path / "bad.txt"
    path.write_text("1 2 3 4 5 6 7 8\n1 2 3\n")
    with pytest.raises(InputError, match=r"bad.txt:2: expected 8 fields"):
        read_relations(path)
    path.write_text("1 2 3 4 5 6 7 x\n")
    with pytest.raises(InputError, match=r"bad.txt:1: every field must be a number"):
        read_relations(path)


def test_intel_relations_match_raw_log(datasets):
    rel = read_relations(datasets / "intel" / "intel.relations")
    assert len(rel) == 2984
    log = open_log(datasets / "intel" / "intel.clf")
    matched, missed = match_relations(rel, log.timestamps)
    assert missed == 0 and len(matched) == 2984
    # Relations are rigid-body motions the odometry roughly agrees with over short spans.
    odo = log.odometry_poses()
    from vgm_studio.core import se2

    short = [m for m in matched if m.b - m.a < 30]
    err = [se2.pose_error(m.pose, se2.between(odo[m.a], odo[m.b]))[0] for m in short]
    assert len(short) > 100 and np.median(err) < 0.2
