"""Training runs: the paper's network learns, and a stopped run goes on where it was."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from vgm_studio.errors import InputError
from vgm_studio.model.features import PairSample
from vgm_studio.model.fitting import Recipe, Rows, fit_network
from vgm_studio.model.precise_bn import precise_batch_norm
from vgm_studio.model.registry import build_network
from vgm_studio.model.validator import input_spec
from vgm_studio.vgm import VGMParams


def matched_pairs(count: int, seed: int) -> tuple[list[PairSample], np.ndarray]:
    """Walls seen twice: a success when the second view lies on the first, a failure when
    it is slid 0.6 m along the room (what a corridor's false match looks like)."""
    rng = np.random.default_rng(seed)
    samples, labels = [], []
    for k in range(count):
        t = rng.uniform(-6, 6, 240)
        walls = np.c_[t, np.where(rng.random(240) < 0.5, -1.5, 1.5)]
        walls[:60] = np.c_[np.full(60, 5.0), rng.uniform(-1.5, 1.5, 60)]  # an end wall
        cur = walls + rng.normal(0, 0.01, walls.shape)
        ok = k % 2 == 0
        if not ok:
            cur = cur + np.array([0.6, 0.0])
        samples.append(PairSample(walls.astype(np.float32), cur.astype(np.float32), 0.7, 0.02))
        labels.append(ok)
    return samples, np.array(labels)


@pytest.mark.long
def test_paper_network_takes_the_400_grid_and_learns_a_tiny_set():
    torch.manual_seed(0)
    net, hyper = build_network("vgmnet-paper", {})
    spec = input_spec("vgmnet-paper", hyper, VGMParams())
    samples, labels = matched_pairs(8, seed=1)
    x, extra = spec.tensors(samples, torch.device("cpu"))
    assert extra is None and tuple(x.shape) == (8, 2, 400, 400)
    assert tuple(net(x).shape) == (8,)
    y = torch.from_numpy(labels.astype(np.float32))
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-3)
    losses = []
    for _ in range(12):
        loss = torch.nn.functional.binary_cross_entropy_with_logits(net(x), y)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(float(loss.detach()))
    # Twelve steps on one batch: the paper's layers fit it (the loss falls well below
    # chance's 0.69), so gradients reach every layer through the 400 × 400 input.
    assert losses[-1] < 0.5 * losses[0], losses


def _fit(rows: Rows, recipe: Recipe, resume=None, stop_after: int | None = None):
    torch.manual_seed(3)
    net, hyper = build_network("vgmnet", {"figures": True})
    spec = input_spec("vgmnet", hyper, VGMParams())

    def hook(done: int, _planned: int) -> None:
        if stop_after is not None and done == stop_after:
            raise KeyboardInterrupt

    return fit_network(net, spec, rows, recipe, on_epoch=hook, resume=resume)


@pytest.fixture(scope="module")
def rows() -> Rows:
    samples, labels = matched_pairs(48, seed=2)
    idx = np.arange(48)
    return Rows(samples, labels, idx[idx % 4 != 0], idx[idx % 4 == 0])


def test_a_stopped_run_resumed_ends_where_an_unbroken_one_does(rows, tmp_path):
    recipe = Recipe(epochs=3, epoch_size=64, batch_size=16, patience=9, seed=5)
    whole = _fit(rows, recipe)
    state = tmp_path / "run.partial"
    with pytest.raises(KeyboardInterrupt):
        _fit(rows, recipe, resume=state, stop_after=2)
    assert state.is_file()
    resumed = _fit(rows, recipe, resume=state)
    assert [h["epoch"] for h in resumed.history] == [1, 2, 3]
    assert resumed.history[:2] == [
        {**h, "seconds": resumed.history[i]["seconds"]} for i, h in enumerate(whole.history[:2])
    ]
    for name, weight in whole.state_dict.items():
        torch.testing.assert_close(resumed.state_dict[name], weight, rtol=0, atol=0)
    np.testing.assert_array_equal(resumed.val_p, whole.val_p)


def test_a_state_from_another_run_is_not_used_and_a_broken_one_is_named(rows, tmp_path):
    state = tmp_path / "run.partial"
    with pytest.raises(KeyboardInterrupt):
        _fit(rows, Recipe(epochs=3, epoch_size=32, batch_size=16, seed=5), state, stop_after=1)
    other = _fit(rows, Recipe(epochs=2, epoch_size=32, batch_size=16, seed=6), state)
    assert [h["epoch"] for h in other.history] == [1, 2]  # started over, not at epoch 2
    state.write_bytes(b"not a run")
    with pytest.raises(InputError, match=r"run\.partial.*not a training run state"):
        _fit(rows, Recipe(epochs=2, epoch_size=32, batch_size=16, seed=6), state)


@pytest.mark.parametrize("training", [False, True])
def test_paper_network_from_cells_is_its_dense_forward_and_gradient(training):
    from vgm_studio.model.validator import network_logits

    torch.manual_seed(2)
    net, hyper = build_network("vgmnet-paper", {"dropout": 0.0})
    # In float64: batch norm over fields that are nearly constant magnifies float32's
    # rounding, and this test is after the arithmetic, not the rounding.
    net = net.double().train(training)
    for m in net.modules():  # statistics that are not the identity, as after training
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.05, 0.05)
            m.running_var.uniform_(1e-4, 1e-3)
    spec = input_spec("vgmnet-paper", hyper, VGMParams())
    samples, _ = matched_pairs(6, seed=4)
    samples[2] = PairSample(np.zeros((0, 2), np.float32), samples[2].cur, 0.7, 0.02)
    x, _ = spec.tensors(samples, torch.device("cpu"))
    dense = net(x.double())
    dense.sum().backward()
    want = {n: p.grad.clone() for n, p in net.named_parameters()}
    net.zero_grad()
    got = network_logits(net, spec, samples, torch.device("cpu"))
    got.sum().backward()
    torch.testing.assert_close(got, dense, rtol=1e-9, atol=1e-9)
    assert float(dense.detach().std()) > 1e-3  # the pairs differ, so equal outputs say something
    for name, p in net.named_parameters():
        torch.testing.assert_close(p.grad, want[name], rtol=1e-8, atol=1e-9, msg=name)


def _labelled(count: int, seed: int):
    from vgm_studio.matching.edges import Edge
    from vgm_studio.model.training import LabelledSet

    samples, labels = matched_pairs(count, seed)
    edges = [
        Edge(f"e{k}", "robot.log", "sha", k, k + 1, 0.0, 0.0, "loop", [0, 0, 0], [0, 0, 0])
        for k in range(count)
    ]
    return LabelledSet(edges, samples, labels, [])


def test_a_run_starts_from_the_given_checkpoint_and_refuses_another_model(tmp_path):
    from vgm_studio.model.checkpoint import load_checkpoint
    from vgm_studio.model.training import TrainConfig, train
    from vgm_studio.model.validator import Validator

    data = _labelled(48, seed=6)
    quiet = {"progress": False, "log": lambda _line: None}
    config = TrainConfig(epochs=1, epoch_size=32, batch_size=16, device="cpu")
    first = train(data, config, tmp_path / "a.pt", **quiet)
    # At a learning rate of 0 the weights the run starts from are the ones it ends with.
    still = replace(config, lr=0.0, seed=9, init=str(tmp_path / "a.pt"))
    again = train(data, still, tmp_path / "b.pt", **quiet)
    fresh = train(data, replace(config, lr=0.0, seed=9), tmp_path / "c.pt", **quiet)
    assert first.state_dict is not None and again.state_dict is not None
    names = [n for n in first.state_dict if n.endswith(("weight", "bias"))]
    for name in names:
        torch.testing.assert_close(again.state_dict[name], first.state_dict[name])
    assert any(not torch.equal(fresh.state_dict[n], first.state_dict[n]) for n in names)
    assert load_checkpoint(tmp_path / "b.pt").training["config"]["init"] == str(tmp_path / "a.pt")
    score = train(data, TrainConfig(model="score"), tmp_path / "s.pt", **quiet)
    assert score.model == "score"
    wrong = replace(config, init=str(tmp_path / "s.pt"))
    with pytest.raises(InputError, match=r"s\.pt.*is a score checkpoint"):
        train(data, wrong, tmp_path / "d.pt", **quiet)
    # A run on 10 cm cells records them, its validator builds its VGMs on them, and its
    # weights do not start a run on the paper's 5 cm cells.
    coarse = replace(config, vgm=VGMParams(resolution=0.1))
    assert train(data, coarse, tmp_path / "w.pt", **quiet).vgm == coarse.vgm != first.vgm
    assert Validator.load(tmp_path / "w.pt").vgm == coarse.vgm
    with pytest.raises(InputError, match=r"w\.pt.*other settings"):
        train(data, replace(config, init=str(tmp_path / "w.pt")), tmp_path / "e.pt", **quiet)


def test_a_checkpoint_saved_before_a_hyper_parameter_existed_still_starts_a_run():
    """The bundled model's hyper-parameters predate ``inliers``; a warm start from it must
    still match the network today's defaults build, and not one built otherwise."""
    from vgm_studio.model.checkpoint import Checkpoint
    from vgm_studio.model.context import Context
    from vgm_studio.model.registry import build_network

    net, full = build_network("vgmnet", {"figures": True, "spread": True})
    saved = {k: v for k, v in full.items() if k != "inliers"}
    old = Checkpoint(model="vgmnet", hyper=saved, state_dict=net.state_dict())
    single = Context()
    assert old.starts("vgmnet", full, VGMParams(), single) is not None
    _, variances_alone = build_network("vgmnet", {**full, "inliers": False})
    assert old.starts("vgmnet", variances_alone, VGMParams(), single) is None
    assert old.starts("vgmnet", full, VGMParams(resolution=0.1), single) is None
    # Weights fitted to single scans are no start for a network that reads local maps.
    assert old.starts("vgmnet", full, VGMParams(), Context(neighbours=2)) is None


def test_the_bundled_model_is_what_the_default_inputs_build():
    """The background trainer starts from the bundled model with ``default_hyper``'s inputs:
    a default changed without the bundled model trained again would leave every run cold."""
    from vgm_studio.model.checkpoint import load_checkpoint
    from vgm_studio.model.context import DEFAULT_CONTEXT
    from vgm_studio.model.registry import BUNDLED_MODEL
    from vgm_studio.trainer.fit import FitConfig

    config = FitConfig()
    _, hyper = build_network("vgmnet", config.hyper)
    bundled = load_checkpoint(BUNDLED_MODEL)
    # The background trainer draws its pairs as the bundled model does.
    assert bundled.context == config.context == DEFAULT_CONTEXT
    assert bundled.starts("vgmnet", hyper, config.vgm, config.context) is not None


def test_precise_batch_norm_recomputes_the_statistics_and_leaves_the_learning_alone(rows):
    """With ``bn_batches`` each validation reads batch norm's statistics recomputed over
    training draws: the learnt weights are those of a run without it, to the bit (the draws
    come from a generator of their own), and the buffers are the recomputed ones."""
    recipe = Recipe(epochs=2, epoch_size=48, batch_size=16, patience=9, seed=5)
    plain = _fit(rows, recipe)
    precise = _fit(rows, replace(recipe, bn_batches=3))
    buffers = {"running_mean", "running_var", "num_batches_tracked"}
    moved = False
    for name, weight in plain.state_dict.items():
        if name.rsplit(".", 1)[-1] in buffers:
            moved |= not torch.equal(precise.state_dict[name], weight)
        else:
            torch.testing.assert_close(precise.state_dict[name], weight, rtol=0, atol=0)
    assert moved
    # The buffers hold the plain average of the three batches' statistics.
    torch.manual_seed(3)
    net, hyper = build_network("vgmnet", {"figures": True})
    net.load_state_dict(precise.state_dict)
    spec = input_spec("vgmnet", hyper, VGMParams())
    norms = [m for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    batches = [rows.samples[i : i + 8] for i in (0, 8, 16)]
    # The stem's mean over each dense batch, as a dense forward pass would see it (training
    # itself takes the occupied cells alone and counts the empty positions in closed form).
    with torch.no_grad():
        seen = [
            net.features[0](spec.tensors(batch, torch.device("cpu"))[0]).mean(dim=(0, 2, 3))
            for batch in batches
        ]
    precise_batch_norm(net, spec, batches, [None] * 3, torch.device("cpu"))
    torch.testing.assert_close(norms[0].running_mean, torch.stack(seen).mean(0))
    net.eval()
    assert precise_batch_norm(net, spec, batches, [None] * 3, torch.device("cpu")) == len(norms)
    assert not net.training
