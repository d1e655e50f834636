"""``--loop-precision`` on ``slam``: the loop cut comes from the checkpoint's validation curve."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.model.checkpoint import load_checkpoint, save_checkpoint
from vgm_studio.model.operating import PrecisionCurve
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.tools import cmd


@pytest.fixture(scope="module")
def loop_log(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("loop")
    return simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=1.5), folder)


def _with_curve(path: Path, curve: PrecisionCurve | None) -> Path:
    """The bundled model with a hand-made validation curve (or none, as older files)."""
    checkpoint = load_checkpoint(BUNDLED_MODEL)
    checkpoint.curve = curve
    save_checkpoint(path, checkpoint)
    return path


def _loops_kept(log: Path, model: Path, out: Path, *args: str) -> int:
    cmd.main(["slam", str(log), "--model", str(model), "--json", str(out), *args])
    return json.loads(out.read_text())["loops_kept"]


@pytest.mark.long
def test_loop_precision_cut_applies_to_loops_and_the_higher_cut_wins(loop_log, tmp_path):
    # Precision 0.5 from p ≥ 0 on, 1.0 only from p ≥ 2: asking 0.9 keeps no loop at all,
    # asking 0.4 gives the cut 0, which leaves the checkpoint's own threshold alone.
    curve = PrecisionCurve([0.0, 2.0], [0.5, 1.0], [1.0, 0.0])
    model = _with_curve(tmp_path / "curve.pt", curve)
    plain = _loops_kept(loop_log, model, tmp_path / "a.json", "--loop-threshold", "0")
    assert plain > 0
    low = ("--loop-threshold", "0", "--loop-precision", "0.4")
    assert _loops_kept(loop_log, model, tmp_path / "b.json", *low) == plain
    high = ("--loop-threshold", "0", "--loop-precision", "0.9")
    _loops_kept(loop_log, model, tmp_path / "c.json", *high)
    # No loop passes on the network's p; only turned loops kept on the overlap of their local
    # maps (a judge of its own, to which the network's cuts do not apply) may go in.
    loops = [
        e for e in json.loads((tmp_path / "c.json").read_text())["edges"] if e["kind"] == "loop"
    ]
    assert loops and all(
        e["overlap"] is not None and e["overlap"] >= 0.7 for e in loops if e["kept"]
    )
    assert not any(e["kept"] for e in loops if e["overlap"] is None)
    # --loop-threshold 0.8 with a precision cut of 0: the threshold, the higher, wins.
    both = ("--loop-threshold", "0.8", "--loop-precision", "0.4")
    alone = _loops_kept(loop_log, model, tmp_path / "d.json", "--loop-threshold", "0.8")
    assert _loops_kept(loop_log, model, tmp_path / "e.json", *both) == alone <= plain


def test_checkpoint_without_curve_refuses_loop_precision_in_one_line(loop_log, tmp_path, capsys):
    model = _with_curve(tmp_path / "old.pt", None)
    with pytest.raises(SystemExit) as exit_info:
        _loops_kept(loop_log, model, tmp_path / "x.json", "--loop-precision", "0.99")
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"vgm-studio: error: {model}: keeps no validation precision curve, so "
        "--loop-precision cannot choose a threshold; retrain it or use --loop-threshold"
    ]


def test_studio_predictions_are_cut_at_the_precision(office_edges, tmp_path):
    from vgm_studio.datasets import ReadOptions
    from vgm_studio.labels import LabelStore
    from vgm_studio.workspace import fill_workspace, predict_workspace

    model = _with_curve(tmp_path / "curve.pt", PrecisionCurve([0.0, 0.7], [0.5, 1.0], [1.0, 0.5]))
    store = LabelStore(tmp_path / "ws")
    fill_workspace(store, office_edges, None, ReadOptions())
    predict_workspace(store, model)
    assert store.predictions().threshold == load_checkpoint(model).threshold
    predict_workspace(store, model, precision=0.9)
    preds = store.predictions()
    assert preds.threshold == 0.7 and len(preds.p) == store.count_edges()
    store.close()


def test_label_refuses_loop_precision_without_curve_before_serving(office_edges, tmp_path):
    from benchmarks.studio_browser import free_port
    from tests.test_cli_checks import one_line_error, run

    model = _with_curve(tmp_path / "old.pt", None)
    args = ("--model", model, "--loop-precision", "0.99", "--port", free_port())
    proc = run("label", office_edges, "--workspace", tmp_path / "ws", *args)
    line = one_line_error(proc, 1)
    assert line.endswith(
        f"{model}: keeps no validation precision curve, so --loop-precision "
        "cannot choose a threshold; retrain it or use --loop-threshold"
    )


def test_the_loop_bar_is_the_highest_cut_a_loop_must_pass(tmp_path):
    """``EdgeValidator.loop_bar`` is what a wide sequential retry must reach too: the
    highest of the checkpoint's threshold, ``--loop-threshold`` and the precision cut."""
    from vgm_studio.slam.config import ValidationConfig
    from vgm_studio.slam.validation import EdgeValidator, LocalMaps

    curve = PrecisionCurve([0.0, 2.0], [0.5, 1.0], [1.0, 0.0])
    model = _with_curve(tmp_path / "curve.pt", curve)
    own = load_checkpoint(model).threshold

    def bar(threshold: float | None, precision: float | None = None) -> float | None:
        config = ValidationConfig(model=model, loop_threshold=threshold, loop_precision=precision)
        # No scans to read: the bundled weights' context needs somewhere to find neighbours.
        nowhere = LocalMaps([], np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
        return EdgeValidator(config, [], None, nowhere).loop_bar

    assert bar(0.8) == max(own, 0.8)
    assert bar(None) == own
    assert bar(0.8, 0.9) == 2.0
    assert bar(0.0, 0.4) == own
    assert EdgeValidator(ValidationConfig(validator="none"), [], None).loop_bar is None
