"""The SLAM validator's second look at the edges it is unsure of (``--second-look``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam.config import ValidationConfig
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.validation import EdgeValidator, LocalMaps
from vgm_studio.tools import cmd


@pytest.fixture(scope="module")
def office(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("office")
    return simulate(SimConfig(preset="office", seed=6, num_beams=181, laps=0.3), folder)


def _true_pairs(office, count):
    """The office's first ``count`` keyframes (every fourth scan), their local maps, and each
    consecutive pair's true step and its match from there.

    The bundled model reads local maps: each keyframe's neighbours are placed from the truth.
    """
    log = open_log(office).scans
    keyframes = np.arange(0, len(log), 4)[:count]
    scans = [log[i] for i in keyframes]
    truth = np.array([s.reference for s in scans])
    local = LocalMaps(log, np.array([s.reference for s in log]), keyframes)
    matcher = ScanMatcher()
    steps = [se2.between(truth[k - 1], truth[k]) for k in range(1, len(scans))]
    matches = [matcher.match(scans[k - 1], scans[k], step) for k, step in enumerate(steps, 1)]
    return scans, local, steps, matches


def test_the_slam_validator_looks_again_only_at_the_edges_it_is_unsure_of(office):
    """Matches slid by 0–0.5 m along x, so that the bundled model is sure of some and
    unsure of others: with ``second_look`` 4 the sure ones keep their p(success) to the bit
    and every unsure one moves."""
    scans, local, steps, matches = _true_pairs(office, 40)
    edges = []
    slides = np.linspace(0.0, 0.5, len(steps))
    for k, (step, match, slide) in enumerate(zip(steps, matches, slides, strict=True), start=1):
        slid = dataclasses.replace(match, estimate=se2.compose(step, np.array([slide, 0, 0])))
        edges.append(SlamEdge("loop", k - 1, k, step, slid))

    p = {}
    for turns in (1, 4):
        config = ValidationConfig(model=BUNDLED_MODEL, second_look=turns)
        judged = [dataclasses.replace(e) for e in edges]
        EdgeValidator(config, scans, local=local)(judged)
        p[turns] = np.array([e.p_success for e in judged])
    unsure = (p[1] > 0.02) & (p[1] < 0.98)
    assert 0 < unsure.sum() < len(edges), p[1]
    assert np.array_equal(p[4][~unsure], p[1][~unsure])
    assert np.all(np.abs(p[4][unsure] - p[1][unsure]) > 1e-6)


def test_second_look_is_recorded_and_checked_on_the_command_line(office, tmp_path, capsys):
    out = tmp_path / "run.json"
    cmd.main(["slam", str(office), "--second-look", "2", "--json", str(out)])
    assert json.loads(out.read_text())["settings"]["validation"]["second_look"] == 2
    capsys.readouterr()  # the run's own output: only the refused call's is checked below
    with pytest.raises(SystemExit) as stop:
        cmd.main(["slam", str(office), "--second-look", "0"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--second-look" in err[0]


def test_a_validator_on_one_thread_says_the_same_and_gives_torchs_threads_back(office):
    """SLAM runs the network on one thread (the other cores are the loop threads' and the
    workers'): the same p(success) to the bit, and torch's count as it was after ``close``."""
    import torch

    scans, local, steps, matches = _true_pairs(office, 30)
    edges = [
        SlamEdge("loop", k - 1, k, step, match)
        for k, (step, match) in enumerate(zip(steps, matches, strict=True), start=1)
    ]
    config = ValidationConfig(model=BUNDLED_MODEL)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        p = {}
        for threads in (None, 1):
            judged = [dataclasses.replace(e) for e in edges]
            validator = EdgeValidator(config, scans, local=local, network_threads=threads)
            assert torch.get_num_threads() == (threads or 2)
            validator(judged)
            validator.close()
            assert torch.get_num_threads() == 2
            p[threads] = np.array([e.p_success for e in judged])
        assert np.array_equal(p[None], p[1])
        assert len(np.unique(np.round(p[1], 2))) > 1  # pairs the model tells apart
    finally:
        torch.set_num_threads(before)
