"""The model API for the app and the back end: load once, predict p(success) for many edges."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.special import logit
from torch import nn

from vgm_studio.errors import InputError
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.model.checkpoint import Checkpoint, load_checkpoint, precision_threshold
from vgm_studio.model.features import (
    PairSample,
    figures_matrix,
    folded_cells,
    load_samples,
    rgb_batch,
    vgm_batch,
)
from vgm_studio.model.networks import VGMNet, VGMNetPaper, fuse_batch_norm
from vgm_studio.model.registry import build_network, entry
from vgm_studio.model.score import ScoreModel
from vgm_studio.vgm.grid import VGMParams


def pick_device(device: str) -> torch.device:
    """``auto`` takes CUDA when there is one."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda asked for, but torch sees no CUDA device")
    return torch.device(device)


@dataclass
class InputSpec:
    """How a model's input batch is made from samples."""

    kind: str  # "vgm", "rgb" or "figures"
    vgm: VGMParams
    fold: int = 1
    image: int = 200
    figures: bool = False
    lift: float = 1.0
    occupancy: bool = False
    spread: bool = False
    inliers: bool = True

    def batch(
        self,
        samples: Sequence[PairSample],
        rotations: Sequence[float] | NDArray[np.float64] | None = None,
    ) -> NDArray[Any]:
        if self.kind == "vgm":
            return vgm_batch(
                samples,
                self.vgm,
                rotations,
                fold=self.fold,
                lift=self.lift,
                occupancy=self.occupancy,
            )
        if self.kind == "rgb":
            return rgb_batch(samples, self.image, rotations)
        return figures_matrix(samples, self.spread, self.inliers)

    def tensors(
        self,
        samples: Sequence[PairSample],
        device: torch.device,
        rotations: Sequence[float] | NDArray[np.float64] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The network's inputs: the image batch (channels-last) and the figures, if used."""
        x = torch.from_numpy(self.batch(samples, rotations)).to(device)
        x = x.contiguous(memory_format=torch.channels_last)
        extra = None
        if self.figures:
            figures = figures_matrix(samples, self.spread, self.inliers).astype(np.float32)
            extra = torch.from_numpy(figures).to(device)
        return x, extra


def input_spec(model: str, hyper: dict[str, Any], vgm: VGMParams) -> InputSpec:
    """How ``model``'s inputs are made, from what the registry says it reads."""
    spread = bool(hyper.get("spread", False))
    reads = entry(model).reads
    if reads == "figures":
        return InputSpec("figures", vgm, spread=spread)
    if reads == "rgb":
        return InputSpec("rgb", vgm, image=int(hyper.get("image", 200)))
    fold = int(hyper.get("fold", 1))
    # A folded batch is written already lifted (see VGMNet.forward); unfolded ones are not.
    lift = float(hyper.get("lift", 1.0)) if fold > 1 else 1.0
    occupancy = bool(hyper.get("occupancy", False)) and fold > 1
    figures = bool(hyper.get("figures", False))
    inliers = bool(hyper.get("inliers", True))
    return InputSpec(
        "vgm",
        vgm,
        fold=fold,
        figures=figures,
        lift=lift,
        occupancy=occupancy,
        spread=spread,
        inliers=inliers,
    )


def forward(net: nn.Module, x: torch.Tensor, extra: torch.Tensor | None) -> torch.Tensor:
    """One forward pass; networks built without matcher figures take the image alone."""
    logits: torch.Tensor = net(x, extra) if extra is not None else net(x)
    return logits


# Pairs per network pass on the sparse path at inference: the stem's output for 64 pairs
# (20 MB) is reused from the heap; for 256 (82 MB) each pass maps fresh pages, which costs
# more than the convolutions on a CPU.
_NET_CHUNK = 64


def network_logits(
    net: nn.Module,
    spec: InputSpec,
    samples: Sequence[PairSample],
    device: torch.device,
    rotations: Sequence[float] | NDArray[np.float64] | None = None,
) -> torch.Tensor:
    """The network's logits for a batch, in the mode it is in (training or eval).

    Networks that take the batch's occupied cells (``forward_cells``) are fed those instead of
    dense VGMs, in training as at inference: the same function at a fraction of the cost.
    """
    folded = isinstance(net, VGMNet) and spec.fold > 1
    if spec.kind == "vgm" and (isinstance(net, VGMNetPaper) or folded):
        return _cells_logits(net, spec, samples, device, rotations)
    x, extra = spec.tensors(samples, device, rotations)
    return forward(net, x, extra)


def _cells_logits(
    net: nn.Module,
    spec: InputSpec,
    samples: Sequence[PairSample],
    device: torch.device,
    rotations: Sequence[float] | NDArray[np.float64] | None,
) -> torch.Tensor:
    """``forward_cells`` of the batch's occupied cells, built in one numpy pass; at inference
    the network takes them ``_NET_CHUNK`` pairs at a time (in training, batch norm's
    statistics are the whole batch's)."""
    assert isinstance(net, VGMNet | VGMNetPaper)
    cells = folded_cells(
        samples, spec.vgm, rotations, fold=spec.fold, lift=spec.lift, occupancy=spec.occupancy
    )
    figures = (
        figures_matrix(samples, spec.spread, spec.inliers).astype(np.float32)
        if spec.figures
        else None
    )
    step = cells.batch if net.training else _NET_CHUNK
    # Cells come sorted by pair, so each chunk's cells are one slice.
    bounds = np.searchsorted(cells.pair, np.arange(0, cells.batch + step, step))
    out = []
    for start in range(0, cells.batch, step):
        count = min(step, cells.batch - start)
        mine = slice(bounds[start // step], bounds[start // step + 1])
        index = (cells.pair[mine] - start) * cells.side * cells.side + cells.position[mine]
        extra = None
        if figures is not None:
            extra = torch.from_numpy(figures[start : start + count]).to(device)
        out.append(
            net.forward_cells(
                count,
                cells.side,
                torch.from_numpy(index).to(device),
                torch.from_numpy(cells.channel[mine]).to(device),
                torch.from_numpy(cells.value[mine]).to(device),
                extra,
            )
        )
    return torch.cat(out)


@dataclass(frozen=True)
class SecondLook:
    """A second look at the pairs the network is unsure of: their logits averaged over the
    pair turned by ``turns`` evenly spaced rotations, the first look's among them.

    The networks were trained on pairs turned at random, so each turn is another draw of the
    grid's cells: an ensemble of one network. Pairs it is sure of are not looked at again:
    looking again at every pair gave the same accuracy on each of the eleven buildings' loops
    (``benchmarks/bench_generalisation.py --second-look``).

    Attributes:
        turns: Rotations in all, the unturned one included (1: no second look).
        band: The first look's p(success) range, both ends excluded, that gets a second.
    """

    turns: int = 4
    band: tuple[float, float] = (0.02, 0.98)


def batched_logits(
    net: nn.Module,
    spec: InputSpec,
    samples: Sequence[PairSample],
    device: torch.device,
    batch_size: int,
    second_look: SecondLook | None = None,
) -> NDArray[np.float64]:
    """The network's logits for every sample, in eval mode, ``batch_size`` at a time; with
    ``second_look``, those in its band averaged over its turns."""
    net.eval()
    out = _logits(net, spec, samples, device, batch_size)
    if second_look is None or second_look.turns < 2:
        return out
    lo, hi = logit(second_look.band)
    unsure = np.flatnonzero((out > lo) & (out < hi))
    if len(unsure) == 0:
        return out
    again = [samples[int(i)] for i in unsure]
    total = out[unsure].copy()
    for k in range(1, second_look.turns):
        turn = 2.0 * np.pi * k / second_look.turns
        total += _logits(net, spec, again, device, batch_size, turn)
    out[unsure] = total / second_look.turns
    return out


def _logits(
    net: nn.Module,
    spec: InputSpec,
    samples: Sequence[PairSample],
    device: torch.device,
    batch_size: int,
    turn: float = 0.0,
) -> NDArray[np.float64]:
    out = np.empty(len(samples), dtype=np.float64)
    with torch.inference_mode():
        for start in range(0, len(samples), batch_size):
            chunk = samples[start : start + batch_size]
            rotations = np.full(len(chunk), turn) if turn else None
            logits = network_logits(net, spec, chunk, device, rotations)
            out[start : start + len(chunk)] = logits.float().cpu().numpy()
    return out


class Validator:
    """A trained model that says p(success) for matched scan pairs.

    Example:
        >>> validator = Validator.load("assets/models/vgmnet-default.pt")
        >>> p = validator.predict(edges)          # one p(success) per edge
    """

    def __init__(
        self,
        checkpoint: Checkpoint,
        device: str = "auto",
        path: Path | None = None,
        second_look: SecondLook | None = None,
    ) -> None:
        self.checkpoint = checkpoint
        self.second_look = second_look
        self.path = path
        self.name = checkpoint.model
        self.vgm = checkpoint.vgm
        self.context = checkpoint.context
        self.hyper = checkpoint.hyper
        self.threshold = checkpoint.threshold
        self.device = pick_device(device)
        self.network: nn.Module | None = None
        self.inference: nn.Module | None = None
        self.score: ScoreModel | None = None
        if entry(self.name).holds == "score":
            self.score = ScoreModel(**(checkpoint.score or {}))
            self.spec = input_spec(self.name, self.hyper, self.vgm)
        else:
            # The full hyper-parameters (defaults included) decide how inputs are made.
            net, full = build_network(self.name, self.hyper)
            self.spec = input_spec(self.name, full, self.vgm)
            net.load_state_dict(checkpoint.state_dict or {})
            net.eval()
            self.network = net.to(self.device).to(memory_format=torch.channels_last)  # type: ignore[call-overload]
            # Batch norm folded into the convolutions: the same values, one pass fewer.
            self.inference = fuse_batch_norm(self.network)

    @classmethod
    def load(
        cls,
        path: str | Path,
        device: str = "auto",
        expect_vgm: VGMParams | None = None,
        second_look: SecondLook | None = None,
    ) -> Validator:
        """Loads a checkpoint; ``expect_vgm`` refuses one trained on other VGM parameters;
        ``second_look`` looks again at the pairs the network is unsure of."""
        path = Path(path)
        return cls(load_checkpoint(path, expect_vgm), device, path, second_look)

    @contextmanager
    def threads(self, count: int) -> Iterator[None]:
        """The network runs on ``count`` of torch's threads inside the block; torch's count is
        the process's, so the one before is put back after."""
        before = torch.get_num_threads()
        torch.set_num_threads(count)
        try:
            yield
        finally:
            torch.set_num_threads(before)

    @property
    def metrics(self) -> dict[str, Any]:
        """The validation metrics recorded at training time."""
        return dict(self.checkpoint.metrics)

    def require_single_scans(self, user: str) -> None:
        """Refuses a validator that reads local maps where ``user`` gives it single scans.

        Raises:
            InputError: It was trained with ``--context``.
        """
        if self.context.neighbours > 0:
            raise InputError(
                self.path,
                f"reads each scan with {self.context.neighbours} neighbours a side "
                f"(trained with --context); {user} gives single scans: use a model trained "
                "with --context 0",
            )

    def threshold_at_precision(self, precision: float) -> float:
        """The lowest p(success) cut whose validation precision reaches ``precision``.

        Raises:
            InputError: No validation curve in the checkpoint, or no cut reaches it.
        """
        return precision_threshold(self.checkpoint, precision, self.path)

    def predict_samples(
        self,
        samples: Sequence[PairSample],
        batch_size: int = 256,
        second_look: SecondLook | None = None,
    ) -> NDArray[np.float64]:
        """p(success) for each sample, computed in batches; ``second_look`` (else the one
        this validator was loaded with) looks again at the pairs the network is unsure of.
        Each side must be drawn with the validator's ``context`` (``predict`` does that)."""
        if self.score is not None:
            return self.score.predict(figures_matrix(samples, len(self.score.mean) == 4))
        assert self.inference is not None
        logits = batched_logits(
            self.inference,
            self.spec,
            samples,
            self.device,
            batch_size,
            second_look or self.second_look,
        )
        return np.asarray(1.0 / (1.0 + np.exp(-logits)))

    def decide(self, probabilities: NDArray[np.float64]) -> NDArray[np.bool_]:
        """True (keep the edge) where p(success) reaches the checkpoint's threshold."""
        return np.asarray(probabilities) >= self.threshold

    def predict(
        self,
        edges: Sequence[Edge],
        scans: EdgeScans | None = None,
        batch_size: int = 256,
        progress: bool = False,
    ) -> NDArray[np.float64]:
        """p(success) for each edge; the edges' logs are read once through ``scans``, each
        side drawn with the validator's ``context``."""
        samples = load_samples(edges, scans, progress=progress, context=self.context)
        return self.predict_samples(samples, batch_size)
