"""The cut and precision curve are chosen on real logs' validation edges, not our worlds'."""

from __future__ import annotations

import numpy as np
import pytest

from vgm_studio.matching.edges import Edge
from vgm_studio.model.calibration import MIN_PER_CLASS, calibrate, calibration_mask
from vgm_studio.model.checkpoint import Checkpoint
from vgm_studio.simulation.simulate import SimConfig, is_simulated, simulate


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("logs")
    sim = simulate(SimConfig(preset="corridor", seed=3, laps=0.2, num_beams=91), folder)
    real = folder / "robot.log"
    ranges = " ".join(["2.5"] * 181)
    real.write_text(f"FLASER 181 {ranges} 0 0 0 0 0 0 1.0 host 1.0\n", encoding="utf-8")
    return sim, real


def _edges(paths: list[str]) -> list[Edge]:
    return [
        Edge(f"e{k}", p, "", k, k + 1, 0.0, 0.0, "loop", [0, 0, 0], [0, 0, 0])
        for k, p in enumerate(paths)
    ]


def test_simulated_logs_are_told_from_others(logs, tmp_path):
    sim, real = logs
    assert is_simulated(sim)
    assert not is_simulated(real)
    assert not is_simulated(tmp_path / "missing.log")


def test_real_validation_edges_choose_the_cut_when_each_class_has_enough(logs):
    sim, real = logs
    n = MIN_PER_CLASS
    paths = [str(real)] * (2 * n) + [str(sim)] * 40
    labels = np.r_[np.ones(n, bool), np.zeros(n, bool), np.ones(30, bool), np.zeros(10, bool)]
    mask = calibration_mask(_edges(paths), labels)
    np.testing.assert_array_equal(mask, np.r_[np.ones(2 * n, bool), np.zeros(40, bool)])
    # One real success short of the minimum: every validation edge chooses.
    assert calibration_mask(_edges(paths[1:]), labels[1:]).all()


def test_cut_and_its_figures_from_the_real_rows_the_curve_from_all():
    # Real logs' rows: successes from p 0.2 up, failures to 0.15: cuts 0.16–0.20 are all
    # right, and ties go to the one nearest 0.5. With the simulated rows (failures up to
    # 0.45) it would be 0.46.
    real_p = np.r_[np.linspace(0.2, 0.9, 40), np.linspace(0.02, 0.15, 40)]
    real_y = np.r_[np.ones(40, bool), np.zeros(40, bool)]
    sim_p = np.r_[np.linspace(0.5, 0.9, 200), np.linspace(0.3, 0.45, 100)]
    sim_y = np.r_[np.ones(200, bool), np.zeros(100, bool)]
    labels, probs = np.r_[real_y, sim_y], np.r_[real_p, sim_p]
    real = np.r_[np.ones(80, bool), np.zeros(300, bool)]
    checkpoint = Checkpoint("score")
    calibrate(checkpoint, labels, probs, real)
    assert checkpoint.threshold == pytest.approx(0.2)
    assert checkpoint.metrics["n"] == 80 and checkpoint.metrics["accuracy"] == 1.0
    # The curve holds every row: at its lowest cut, recall 1 and the whole set's precision.
    assert checkpoint.curve is not None
    assert checkpoint.curve.precision[0] == pytest.approx(240 / 380)
    calibrate(checkpoint, labels, probs, np.ones(380, bool))
    assert checkpoint.threshold == pytest.approx(0.46)
