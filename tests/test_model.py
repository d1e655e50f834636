"""Models: metrics, features, training a tiny model, checkpoints and the Validator API."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from vgm_studio.datasets import open_log
from vgm_studio.errors import InputError
from vgm_studio.matching.candidates import CandidateConfig, make_candidates
from vgm_studio.matching.edges import write_edges
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.model.features import PairSample, rgb_plot, vgm_batch
from vgm_studio.model.metrics import binary_metrics, paired_comparison, roc_auc
from vgm_studio.model.training import (
    TrainConfig,
    choose_threshold,
    read_labelled,
    stratified_split,
    train,
)
from vgm_studio.model.validator import Validator
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.vgm import VGMParams, pair_map


def test_metrics_against_hand_computed_values():
    labels = [True, True, False, False, True]
    probs = [0.9, 0.4, 0.3, 0.6, 0.8]
    m = binary_metrics(labels, probs)
    # At 0.5: TP = {0.9, 0.8}, FN = {0.4}, FP = {0.6}, TN = {0.3}.
    assert (m["tp"], m["fn"], m["fp"], m["tn"], m["n"]) == (2, 1, 1, 1, 5)
    assert m["accuracy"] == pytest.approx(3 / 5)
    assert m["precision"] == pytest.approx(2 / 3)
    assert m["recall"] == pytest.approx(2 / 3)
    assert m["f1"] == pytest.approx(2 / 3)
    # 5 of the 6 (positive, negative) pairs are ordered right.
    assert m["auc"] == pytest.approx(5 / 6)
    assert binary_metrics(labels, probs, threshold=0.35)["tp"] == 3
    # A tie counts one half.
    assert roc_auc([True, False], [0.5, 0.5]) == pytest.approx(0.5)
    assert np.isnan(roc_auc([True, True], [0.1, 0.2]))
    nothing_predicted = binary_metrics([True, False], [0.1, 0.2])
    assert nothing_predicted["precision"] == 0.0 and nothing_predicted["f1"] == 0.0


def test_paired_comparison_against_hand_computed_values():
    # Pairs both get right or both get wrong carry no evidence; of the 7 they split on, the
    # first is right on 5: P(a 5/2 split or more uneven, either way) = 2 (1 + 7 + 21) / 2^7.
    first = [True] * 5 + [False] * 2 + [True, False]
    second = [False] * 5 + [True] * 2 + [True, False]
    c = paired_comparison(first, second)
    assert (c.only_first, c.only_second) == (5, 2)
    assert c.p_value == pytest.approx(58 / 128)
    # One model right on all 8 pairs they split on: 2 / 2^8.
    assert paired_comparison([True] * 8, [False] * 8).p_value == pytest.approx(2 / 256)
    assert paired_comparison([True, False], [True, False]).p_value == 1.0
    with pytest.raises(ValueError, match="judged on"):
        paired_comparison([True], [True, False])


def test_threshold_chosen_on_validation():
    labels = np.array([True] * 8 + [False] * 2)
    probs = np.array([0.3] * 8 + [0.1] * 2)
    cut = choose_threshold(labels, probs)
    assert 0.1 < cut <= 0.3
    assert binary_metrics(labels, probs, cut)["accuracy"] == 1.0


def test_split_holds_out_every_group_and_label():
    labels = np.array([True] * 40 + [False] * 20 + [True] * 30 + [False] * 10)
    groups = ["a"] * 60 + ["b"] * 40
    tr, va = stratified_split(labels, groups, 0.25, seed=1)
    assert len(set(tr) & set(va)) == 0 and len(tr) + len(va) == 100
    for g, y, n in (("a", True, 40), ("a", False, 20), ("b", True, 30), ("b", False, 10)):
        held = [i for i in va if groups[i] == g and labels[i] == y]
        assert len(held) == round(0.25 * n)
    assert np.array_equal(stratified_split(labels, groups, 0.25, seed=1)[1], va)


def random_samples(count: int, seed: int) -> list[PairSample]:
    """Pairs of random Gaussian point clouds of different sizes, with made-up figures."""
    rng = np.random.default_rng(seed)
    return [
        PairSample(
            rng.normal(0, 4, (300, 2)).astype(np.float32),
            rng.normal(0, 4, (280, 2)).astype(np.float32),
            0.5,
            0.01,
        )
        for _ in range(count)
    ]


def test_folded_vgm_batch_equals_pixel_unshuffle_of_pair_map():
    samples = random_samples(3, seed=0)
    params = VGMParams()
    dense = vgm_batch(samples, params)
    np.testing.assert_array_equal(dense[1], pair_map(samples[1].prev, samples[1].cur, [0, 0, 0]))
    folded = vgm_batch(samples, params, fold=4)
    want = torch.nn.PixelUnshuffle(4)(torch.from_numpy(dense)).numpy()
    np.testing.assert_array_equal(folded, want)
    turned = vgm_batch(samples[:1], params, rotations=[np.pi])
    # A half turn mirrors the grid through its centre.
    np.testing.assert_allclose(turned[0], dense[0][:, ::-1, ::-1], atol=1e-5)


def test_spread_figures_come_from_the_match_covariance():
    from vgm_studio.model.features import figures_matrix, sample_from_scans

    pts = np.zeros((3, 2))
    # xy variances 4e-4 and 1e-2 m², rotated by 30°: the top eigenvalue is still 1e-2.
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    rot = np.array([[c, -s], [s, c]])
    cov = np.zeros((3, 3))
    cov[:2, :2] = rot @ np.diag([4e-4, 1e-2]) @ rot.T
    cov[2, 2] = 1e-6
    figures = {"inlier_ratio": 0.8, "residual": 0.01, "covariance": cov.tolist()}
    sample = sample_from_scans(pts, pts, [0.0, 0.0, 0.0], figures)
    assert sample.spread_xy == pytest.approx(-2.0) and sample.spread_theta == pytest.approx(-6.0)
    degenerate = sample_from_scans(pts, pts, [0.0, 0.0, 0.0], {**figures, "covariance": None})
    assert (degenerate.spread_xy, degenerate.spread_theta) == (0.0, 0.0)
    both = figures_matrix([sample, degenerate], spread=True)
    np.testing.assert_allclose(both, [[0.8, -2.0, -2.0, -6.0], [0.8, -2.0, 0.0, 0.0]])
    assert figures_matrix([sample], spread=False).shape == (1, 2)
    # The variances alone: the matcher's inlier ratio and residual left out.
    np.testing.assert_allclose(
        figures_matrix([sample, degenerate], True, inliers=False), both[:, 2:]
    )
    assert figures_matrix([sample], spread=False, inliers=False).shape == (1, 0)


def test_rgb_plot_colours():
    s = PairSample(np.array([[1.0, 0.0]], np.float32), np.array([[0.0, 5.0]], np.float32), 1, 0)
    img = rgb_plot(s, size=200, extent=20.0)
    # +x right, +y up: (1, 0) is right of centre, (0, 5) above it.
    assert img[100, 110, 0] == 255 and img[100, 110, 1] == 0
    assert img[50, 100, 1] == 255 and img[50, 100, 0] == 0


@pytest.fixture(scope="module")
def sim_edges(tmp_path_factory):
    """Labelled edges of two simulated logs: one to train on, one held out."""
    folder = tmp_path_factory.mktemp("edges")
    files = []
    for name, seed in (("train", 21), ("held", 22)):
        log = open_log(
            simulate(SimConfig(preset="repetitive", seed=seed, laps=1.2, num_beams=181), folder)
        )
        edges = make_candidates(
            log,
            ScanMatcher(),
            CandidateConfig(max_loops=500, seed=seed, keyframe_distance=1.0),
            progress=False,
        )
        files.append(folder / f"{name}.jsonl")
        write_edges(files[-1], edges)
    return files


def test_tiny_model_beats_chance_on_held_out_log(sim_edges, tmp_path):
    data = read_labelled([sim_edges[0]], progress=False)
    held = read_labelled([sim_edges[1]], progress=False)
    assert data.labels.sum() > 30 and (~data.labels).sum() > 30
    config = TrainConfig(
        model="vgmnet",
        epochs=3,
        epoch_size=768,
        batch_size=32,
        seed=0,
        device="cpu",
        hyper={"figures": False},
    )
    out = tmp_path / "tiny.pt"
    checkpoint = train(data, config, out, progress=False, log=lambda _: None)
    assert out.is_file() and len(checkpoint.training["config"]) > 5
    validator = Validator.load(out)
    probs = validator.predict_samples(held.samples)
    m = binary_metrics(held.labels, probs, validator.threshold)
    balanced = 0.5 * (m["tp"] / (m["tp"] + m["fn"]) + m["tn"] / (m["tn"] + m["fp"]))
    # Chance is 0.5 for both; three short epochs on one small log already do much better.
    assert m["auc"] > 0.65, m
    assert balanced > 0.58, m


def test_checkpoint_round_trip_and_refusals(sim_edges, tmp_path):
    data = read_labelled([sim_edges[0]], progress=False)
    out = tmp_path / "score.pt"
    checkpoint = train(data, TrainConfig(model="score"), out, progress=False, log=lambda _: None)
    assert checkpoint.training["files"][0]["sha256"]
    assert checkpoint.training["counts"]["train"]["failure"] > 0
    v = Validator.load(out, expect_vgm=VGMParams())
    assert v.name == "score" and v.vgm == VGMParams()
    assert v.metrics["n"] == sum(checkpoint.training["counts"]["validation"].values())
    curve = v.checkpoint.curve  # kept for --loop-precision
    assert curve is not None and 1 < len(curve.thresholds) <= v.metrics["n"]
    assert curve.recall[0] == 1.0 and curve.thresholds == sorted(curve.thresholds)
    again = Validator.load(out)
    np.testing.assert_array_equal(
        v.predict_samples(data.samples[:20]), again.predict_samples(data.samples[:20])
    )

    with pytest.raises(InputError, match=r"trained on VGMs of size 400.*size 200"):
        Validator.load(out, expect_vgm=replace(VGMParams(), size=200))
    broken = tmp_path / "broken.pt"
    broken.write_bytes(out.read_bytes()[:100])
    with pytest.raises(InputError, match="not a readable model checkpoint"):
        Validator.load(broken)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(InputError, match="not a VGM Studio model"):
        Validator.load(foreign)
    with pytest.raises(InputError, match="no such model file"):
        Validator.load(tmp_path / "none.pt")


def test_validator_predicts_edges_from_their_logs(sim_edges, tmp_path):
    data = read_labelled([sim_edges[1]], progress=False)
    out = tmp_path / "rgb.pt"
    train(
        data,
        TrainConfig(model="rgb-baseline", epochs=1, epoch_size=64, batch_size=32, device="cpu"),
        out,
        progress=False,
        log=lambda _: None,
    )
    v = Validator.load(out)
    p_edges = v.predict(data.edges[:10])
    p_samples = v.predict_samples(data.samples[:10])
    np.testing.assert_allclose(p_edges, p_samples, atol=1e-6)
    assert np.all((p_edges >= 0) & (p_edges <= 1))
    assert v.decide(np.array([v.threshold, v.threshold - 0.01])).tolist() == [True, False]


def test_unknown_model_and_one_class(sim_edges, tmp_path):
    data = read_labelled([sim_edges[0]], progress=False)
    with pytest.raises(InputError, match="unknown model"):
        train(data, TrainConfig(model="resnet"), tmp_path / "x.pt", progress=False)
    only = replace(data, labels=np.ones_like(data.labels))
    with pytest.raises(InputError, match="0 failure edges; training needs at least 10 of each"):
        train(only, TrainConfig(model="score"), tmp_path / "x.pt", progress=False)


def test_files_without_labels_are_refused(tmp_path):
    from vgm_studio.matching.edges import Edge

    path = tmp_path / "unlabelled.jsonl"
    write_edges(path, [Edge("e", "x.log", "h", 0, 1, 0.0, 1.0, "loop", [0, 0, 0], [0, 0, 0])])
    with pytest.raises(InputError, match="no edge labelled success or failure"):
        read_labelled([Path(path)], progress=False)


@pytest.mark.long
def test_train_and_eval_commands(sim_edges, tmp_path):
    import json
    import subprocess
    import sys

    def cli(*args):
        return subprocess.run(
            [sys.executable, "-m", "vgm_studio.tools.cmd", *map(str, args)],
            capture_output=True,
            text=True,
            timeout=600,
        )

    model = tmp_path / "score.pt"
    trained = cli("train", sim_edges[0], "--model", "score", "--out", model)
    assert trained.returncode == 0, trained.stderr
    assert "validation: accuracy" in trained.stdout
    report = tmp_path / "eval.json"
    proc = cli("eval", model, sim_edges[1], "--json", report)
    assert proc.returncode == 0, proc.stderr
    assert "ROC AUC" in proc.stdout and "TP" in proc.stdout
    figures = json.loads(report.read_text())
    held = read_labelled([sim_edges[1]], progress=False)
    v = Validator.load(model)
    want = binary_metrics(held.labels, v.predict_samples(held.samples), v.threshold)
    for key in ("accuracy", "precision", "recall", "f1", "auc", "tp", "fp", "tn", "fn", "n"):
        assert figures[key] == pytest.approx(want[key]), key
    assert figures["tp"] + figures["fp"] + figures["tn"] + figures["fn"] == figures["n"]

    bad = cli("train", sim_edges[0], "--model", "transformer", "--out", model)
    assert bad.returncode == 2 and "--model" in bad.stderr and "Traceback" not in bad.stderr
    wrong_suffix = cli("train", sim_edges[0], "--out", tmp_path / "m.bin")
    assert wrong_suffix.returncode == 2 and ".pt" in wrong_suffix.stderr
    missing = cli("eval", tmp_path / "none.pt", sim_edges[1])
    assert missing.returncode == 1 and "no such model file" in missing.stderr
    coarse = cli("train", sim_edges[0], "--model", "score", "--cell-size", 0.1, "--out", model)
    assert coarse.returncode == 0, coarse.stderr
    assert Validator.load(model).vgm == VGMParams(resolution=0.1)
    zero = cli("train", sim_edges[0], "--cell-size", 0, "--out", model)
    assert zero.returncode == 2 and "--cell-size" in zero.stderr and "Traceback" not in zero.stderr
    # Switches that would build a network with nothing for its figures head to read.
    for flags, named in (
        (("--no-inliers", "--no-spread"), "--no-inliers"),
        (("--no-figures", "--blind-head"), "--blind-head"),
    ):
        refused = cli("train", sim_edges[0], *flags, "--out", tmp_path / "x.pt")
        assert refused.returncode == 2 and named in refused.stderr, refused.stderr
        assert "Traceback" not in refused.stderr and not (tmp_path / "x.pt").exists()


@pytest.mark.parametrize(
    ("occupancy", "spread", "inliers"),
    [(False, False, True), (True, True, True), (False, True, False)],
)
def test_prefolded_lifted_input_matches_network_on_raw_vgms(occupancy, spread, inliers):
    from vgm_studio.model.features import figures_matrix
    from vgm_studio.model.registry import build_network
    from vgm_studio.model.validator import input_spec

    torch.manual_seed(0)
    net, hyper = build_network(
        "vgmnet", {"figures": True, "occupancy": occupancy, "spread": spread, "inliers": inliers}
    )
    net.eval()
    spec = input_spec("vgmnet", hyper, VGMParams())
    assert spec.fold == 8 and spec.lift == 0.5 and spec.occupancy == occupancy
    samples = random_samples(3, seed=3)
    x, extra = spec.tensors(samples, torch.device("cpu"))
    raw = torch.from_numpy(vgm_batch(samples, VGMParams()).copy())
    figs = torch.from_numpy(figures_matrix(samples, spread, inliers).astype(np.float32))
    assert extra is not None and extra.shape == (3, 2 * inliers + 2 * spread)
    with torch.inference_mode():
        np.testing.assert_allclose(net(x, extra).numpy(), net(raw, figs).numpy(), atol=1e-5)


@pytest.mark.parametrize("occupancy", [False, True])
def test_batched_cells_path_equals_dense_network(tmp_path, occupancy):
    from vgm_studio.model.checkpoint import Checkpoint, save_checkpoint
    from vgm_studio.model.registry import build_network
    from vgm_studio.model.validator import Validator, input_spec

    torch.manual_seed(1)
    net, hyper = build_network("vgmnet", {"figures": True, "occupancy": occupancy})
    # Batch norm with statistics that are not the identity, as after training.
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
            m.weight.data.uniform_(0.5, 1.5)
    path = tmp_path / "m.pt"
    state = {k: v.clone() for k, v in net.state_dict().items()}
    save_checkpoint(path, Checkpoint("vgmnet", hyper=hyper, state_dict=state))
    samples = random_samples(70, seed=4)
    empty = np.zeros((0, 2), np.float32)
    samples[5] = PairSample(empty, empty, 0.0, 0.02)  # a pair with no point on the grid
    samples[9] = PairSample(np.array([[0.3, 0.2]], np.float32), empty, 1.0, 0.0)
    net.eval()
    spec = input_spec("vgmnet", hyper, VGMParams())
    x, extra = spec.tensors(samples, torch.device("cpu"))
    with torch.inference_mode():
        want = torch.sigmoid(net(x, extra)).numpy()
    got = Validator.load(path, device="cpu").predict_samples(samples, batch_size=256)
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert np.ptp(got) > 1e-3  # the pairs do differ, so the comparison says something


def test_train_command_defaults_are_the_train_config_defaults():
    """The command line spells its defaults (it must not load torch to start), so they are
    checked against the config the benchmarks and ``train_default.py`` rely on."""
    import inspect

    from vgm_studio.model.training import TrainConfig
    from vgm_studio.tools.model_cmds import train as train_command

    defaults = TrainConfig()
    params = inspect.signature(train_command).parameters
    shared = ["epochs", "batch_size", "lr", "patience", "val_fraction", "epoch_size"]
    shared += ["max_train", "augment", "occlude", "seed", "bn_batches", "threads"]
    for name in shared:
        assert params[name].default == getattr(defaults, name), name
    assert params["cell_size"].default == defaults.vgm.resolution


@pytest.mark.parametrize("occupancy", [False, True])
def test_cells_path_trains_as_the_dense_network(occupancy):
    """A training step through the occupied cells gives the dense network's loss, gradients
    and batch-norm running statistics (the stem's batch statistics count the empty positions
    in closed form). The reference is the dense network in float64. In float32 the dense
    network's own batch-norm backward is up to 11% off it on 12 pairs, and how far depends
    on the threads' summation order; the cells path must be no farther off than that, or
    within 0.5% (it is within 0.01% on two threads, 5% on one)."""
    import copy

    from vgm_studio.model.registry import build_network
    from vgm_studio.model.validator import forward, input_spec, network_logits

    torch.manual_seed(2)
    cells, hyper = build_network("vgmnet", {"figures": True, "occupancy": occupancy})
    dense = copy.deepcopy(cells).double()
    dense32 = copy.deepcopy(cells)
    spec = input_spec("vgmnet", hyper, VGMParams())
    samples = random_samples(12, seed=5)
    empty = np.zeros((0, 2), np.float32)
    samples[3] = PairSample(empty, empty, 0.0, 0.02)  # a pair with no point on the grid
    turns = np.linspace(0.0, 5.0, len(samples))
    target = torch.from_numpy(np.arange(len(samples)) % 2 == 0).double()
    x, extra = spec.tensors(samples, torch.device("cpu"), turns)
    assert extra is not None
    losses = []
    for net in (dense, dense32, cells):
        net.train()
        torch.manual_seed(3)  # the same dropout mask on every path
        if net is dense:
            logits = forward(net, x.double(), extra.double())
        elif net is dense32:
            logits = forward(net, x, extra).double()
        else:
            logits = network_logits(net, spec, samples, torch.device("cpu"), turns).double()
        loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, target)
        loss.backward()
        losses.append(float(loss.detach()))
    assert abs(losses[0] - losses[2]) < 1e-5
    params = zip(dense.named_parameters(), dense32.parameters(), cells.parameters(), strict=True)
    for (name, want), plain, got in params:
        assert want.grad is not None and plain.grad is not None and got.grad is not None
        scale = float(want.grad.abs().max())
        assert scale > 1e-6, name  # every layer learns, so the comparison says something
        float32_error = float((plain.grad.double() - want.grad).abs().max())
        error = float((got.grad.double() - want.grad).abs().max())
        assert error <= max(5e-3 * scale, float32_error), name
    for (name, want), got in zip(dense.named_buffers(), cells.buffers(), strict=True):
        np.testing.assert_allclose(
            got.double().numpy(), want.numpy(), rtol=1e-4, atol=1e-6, err_msg=name
        )


def test_second_look_averages_the_turned_pairs_inside_its_band_only(tmp_path):
    """Pairs whose first p(success) lies inside the band get the mean logit over the pair
    turned four ways, each turn computed here on its own; the others keep their first look."""
    from vgm_studio.model.checkpoint import Checkpoint, save_checkpoint
    from vgm_studio.model.registry import build_network
    from vgm_studio.model.validator import SecondLook, Validator, input_spec, network_logits

    torch.manual_seed(2)
    net, hyper = build_network("vgmnet", {"figures": True})
    samples = random_samples(24, seed=5)
    net.eval()
    spec = input_spec("vgmnet", hyper, VGMParams())
    cpu = torch.device("cpu")
    # The last layer scaled so that logits spread over a few units around 0, as a trained
    # network's do near its cut (fresh weights give logits within 1e-3 of each other).
    last = [m for m in net.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.inference_mode():
        z = network_logits(net, spec, samples, cpu).float().numpy()
        scale = 2.0 / float(z.std())
        last.weight.mul_(scale)
        last.bias.copy_((last.bias - float(z.mean())) * scale)
    path = tmp_path / "m.pt"
    save_checkpoint(path, Checkpoint("vgmnet", hyper=hyper, state_dict=net.state_dict()))
    with torch.inference_mode():
        turned = np.stack(
            [
                network_logits(net, spec, samples, cpu, np.full(len(samples), k * np.pi / 2))
                .float()
                .numpy()
                for k in range(4)
            ]
        ).astype(np.float64)
    first = 1.0 / (1.0 + np.exp(-turned[0]))
    band = (float(np.quantile(first, 0.3)), float(np.quantile(first, 0.8)))
    inside = (first > band[0]) & (first < band[1])
    assert 0 < inside.sum() < len(samples)

    look = SecondLook(turns=4, band=band)
    got = Validator.load(path, device="cpu", second_look=look).predict_samples(samples, 10)
    want = np.where(inside, 1.0 / (1.0 + np.exp(-turned.mean(axis=0))), first)
    # The validator runs the network with batch norm folded in: the same to ~1e-5 a logit.
    np.testing.assert_allclose(got, want, atol=1e-4)
    # The turns do disagree, so the pairs inside the band did move.
    moved = np.abs(got - first)[inside]
    assert np.median(moved) > 1e-3, moved
    alone = Validator.load(path, device="cpu").predict_samples(samples, 10)
    np.testing.assert_allclose(alone, first, atol=1e-4)


def test_a_blind_head_is_fitted_on_its_own_loss_and_averaged_in_eval():
    """``blind``: a second head without the figures. Training fits each head to the labels
    (the loss is the mean of the two heads' losses, not the loss of their mean); eval gives
    the mean of the two logits, on the occupied-cells path as on the dense one."""
    from vgm_studio.model.fitting import train_step
    from vgm_studio.model.registry import build_network
    from vgm_studio.model.validator import input_spec, network_logits

    cpu = torch.device("cpu")
    torch.manual_seed(0)
    net, hyper = build_network("vgmnet", {"figures": True, "spread": True, "blind": True})
    assert build_network("vgmnet", {"figures": False, "blind": True})[0].blind is None
    spec = input_spec("vgmnet", hyper, VGMParams())
    samples = random_samples(8, seed=4)
    labels = np.arange(8) % 2 == 0
    net.eval()
    with torch.inference_mode():
        x, extra = spec.tensors(samples, cpu)
        feats = net.features(x)
        want = (net.head(feats, extra) + net.blind(feats)) / 2
        got = network_logits(net, spec, samples, cpu)
    np.testing.assert_allclose(got.numpy(), want.numpy(), atol=1e-5)
    net.train()
    torch.manual_seed(7)
    with torch.no_grad():
        both = network_logits(net, spec, samples, cpu)
    assert both.shape == (8, 2)
    y = torch.from_numpy(labels.astype(np.float32))
    bce = torch.nn.functional.binary_cross_entropy_with_logits
    each = (bce(both[:, 0], y) + bce(both[:, 1], y)) / 2
    assert abs(float(each) - float(bce(both.mean(dim=1), y))) > 1e-4  # the two rules differ
    before = [h.mlp[-1].weight.clone() for h in (net.head, net.blind)]
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-2)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda _step: 1.0)
    torch.manual_seed(7)  # the same dropout masks as above
    loss = train_step(net, spec, samples, labels, None, optimiser, schedule, cpu)
    assert loss == pytest.approx(float(each), abs=1e-5)
    heads = (net.head, net.blind)
    assert all(not torch.equal(b, h.mlp[-1].weight) for b, h in zip(before, heads, strict=True))
