"""The loop search's submaps: held a bounded number at a time, with the same edges."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vgm_studio.datasets import open_log
from vgm_studio.graph.config import GraphConfig
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam import frontend
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import SlamEdge


def _network(edges: list[SlamEdge]) -> None:
    """A validator that trusts a match whose scans agree."""
    for e in edges:
        e.p_success = 0.95 if e.match.inlier_ratio > 0.5 else 0.1
        e.kept = e.validated = e.p_success > 0.5


def _run(scans, odometry, monkeypatch) -> tuple[list[SlamEdge], int]:
    """The front end's edges, and the most submaps it held when it built one."""
    held = []
    build = frontend.FrontEnd._submap

    def spy(self, a, b):
        held.append(len(self._submaps))
        return build(self, a, b)

    monkeypatch.setattr(frontend.FrontEnd, "_submap", spy)
    front = frontend.FrontEnd(
        scans, odometry, ScanMatcher(), _network, FrontEndConfig(), GraphConfig(), loop_bar=0.8
    )
    return front.run(progress=False), max(held)


def test_the_loop_search_holds_few_submaps_and_matches_as_with_many(tmp_path: Path, monkeypatch):
    """A building's final sweep once held every submap it searched (6 GB on freiburg-campus).
    With two held at a time the run builds the same edges, to the bit."""
    log = open_log(simulate(SimConfig(preset="t-junction", seed=3, num_beams=181), tmp_path))
    odometry = np.array([s.odometry for s in log.scans])
    keyframes = select_keyframes(odometry, 0.5, 20.0)
    scans, odometry = [log.scans[i] for i in keyframes], odometry[keyframes]

    many, held_many = _run(scans, odometry, monkeypatch)
    monkeypatch.setattr(frontend, "_SUBMAPS_AT_ONCE", 2)
    few, held_few = _run(scans, odometry, monkeypatch)

    assert held_many > 2  # a block's candidates do need more than two submaps
    assert held_few <= 2
    loops = [e for e in many if e.kind == "loop"]
    assert loops and any(e.kept for e in loops)
    assert len(few) == len(many)
    for x, y in zip(many, few, strict=True):
        assert (x.kind, x.a, x.b, x.kept) == (y.kind, y.a, y.b, y.kept)
        assert np.array_equal(x.estimate, y.estimate)
