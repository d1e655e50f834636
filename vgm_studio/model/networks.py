"""The networks: the paper's VGM-Net, our sparse-aware VGM-Net, and the RGB-plot baseline."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch
from scipy.sparse import csr_matrix
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from vgm_studio.model.sparse_layers import pointwise_at_cells, sparse_block, update_running_stats


def _block(c_in: int, c_out: int, stride: int = 2) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


def _stack(
    stem: list[nn.Module], c_in: int, channels: tuple[int, ...]
) -> tuple[nn.Sequential, int]:
    """``stem`` then one stride-2 block per entry of ``channels``; returns it and its width."""
    layers = list(stem)
    for ch in channels:
        layers.append(_block(c_in, ch))
        c_in = ch
    return nn.Sequential(*layers), c_in


class _PooledHead(nn.Module):
    """Global average and max pooling, then an MLP to one logit (the sigmoid is in the loss).

    ``extra`` scalars (the matcher's figures) join the pooled features when given.
    """

    def __init__(self, channels: int, hidden: int, dropout: float, extra: int = 0) -> None:
        super().__init__()
        self.mlp = nn.Sequential(
            nn.Linear(2 * channels + extra, hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(dropout),
            nn.Linear(hidden, 1),
        )

    def forward(self, x: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        parts = [x.mean(dim=(2, 3)), x.amax(dim=(2, 3))]
        if extra is not None:
            parts.append(extra)
        logit: torch.Tensor = self.mlp(torch.cat(parts, dim=1)).squeeze(1)
        return logit


@dataclass(frozen=True)
class PaperConfig:
    """VGM-Net as the paper's Table 1 gives it; what the paper leaves open is our choice:
    3×3 convolutions with stride 2, batch norm and ReLU after each, global average+max pooling
    before the 256-unit MLP, dropout 0.3."""

    pointwise: int = 16
    channels: tuple[int, ...] = (32, 64, 128, 128)
    hidden: int = 256
    dropout: float = 0.3


class VGMNetPaper(nn.Module):
    """The paper's network: a 1×1 convolution over the two VGM channels, four convolutions
    of 32, 64, 128, 128 filters, a 256-unit MLP and a sigmoid output. Dense over 400×400."""

    def __init__(self, config: PaperConfig | None = None) -> None:
        super().__init__()
        c = config or PaperConfig()
        stem = [nn.Conv2d(2, c.pointwise, 1), nn.ReLU(inplace=True)]
        self.features, width = _stack(stem, c.pointwise, c.channels)
        self.head = _PooledHead(width, c.hidden, c.dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        logit: torch.Tensor = self.head(self.features(x))
        return logit

    def forward_cells(
        self,
        batch: int,
        side: int,
        index: torch.Tensor,
        channel: torch.Tensor,
        value: torch.Tensor,
        extra: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``forward`` of a batch given by its occupied cells, in training as in eval.

        The same function as ``forward`` on the dense 400×400 batch (``VGMNet.forward_cells``
        says how), at a fraction of its cost: over 99% of the cells are empty, and the
        1×1 convolution's 16 channels at every cell were most of the memory a pass moves.

        Args:
            batch: Pairs in the batch.
            side: Grid side.
            index: Each occupied cell's pair·side² + position.
            channel: Each occupied cell's channel (0: previous scan, 1: current).
            value: Each occupied cell's value.
            extra: Not read (the paper's network takes the VGM alone).
        """
        conv = self.features[0]
        first = self.features[2]
        assert isinstance(conv, nn.Conv2d) and conv.bias is not None
        assert isinstance(first, nn.Sequential)
        rows, at = torch.unique(index, return_inverse=True)
        pre = pointwise_at_cells(conv, len(rows), at, channel, value)
        empty = torch.relu(conv.bias)
        x = sparse_block(first, batch, side, rows, torch.relu(pre) - empty, empty)
        logit: torch.Tensor = self.head(self.features[3:](x))
        return logit


@dataclass(frozen=True)
class SparseConfig:
    """Our VGM-Net. The VGM is >99% empty; rather than convolve 160,000 mostly-zero cells,
    fold each ``fold``×``fold`` block of cells (40 cm) into channels first (space-to-depth:
    lossless, every cell's two values are still there), mix them with a 1×1 convolution,
    then run a small strided CNN on the 64× smaller grid. ``figures`` adds the matcher's
    inlier ratio and log residual to the pooled features. ``lift`` raises cell values to
    that power first: the hit ratio n/n_max leaves far, single-point cells near zero, and
    the lift lets them count. ``occupancy`` adds each scan's occupied cells as two more
    channels, every point at equal weight, as the RGB plot baseline sees them. ``spread``
    adds the estimate's log10 position and heading variances to the figures: a match along
    a featureless corridor is free to slide, and its covariance says so. ``inliers`` off
    leaves the inlier ratio and residual out of the figures, the variances alone: how many
    points agree depends on a building's clutter and scan density, more than on the match.
    ``blind`` (with ``figures``) adds a second head that reads the pooled features alone: in
    training each head has its own loss, and the network's logit is the mean of the two. It is
    an ensemble, on one trunk, of a network that reads the figures and one that does not; the
    figures help on long corridors and mislead on buildings unlike the training ones
    (the leave-one-building-out table), and the second head costs one small MLP a pair."""

    fold: int = 8
    pointwise: int = 32
    channels: tuple[int, ...] = (64, 96, 128)
    hidden: int = 128
    dropout: float = 0.3
    figures: bool = False
    lift: float = 0.5
    occupancy: bool = False
    spread: bool = False
    inliers: bool = True
    blind: bool = False


class VGMNet(nn.Module):
    """Space-to-depth VGM-Net: ~20× cheaper per pair than the paper's network on a CPU."""

    def __init__(self, config: SparseConfig | None = None) -> None:
        super().__init__()
        c = config or SparseConfig()
        self.fold = nn.PixelUnshuffle(c.fold)
        self.lift = c.lift
        self.occupancy = c.occupancy
        stem = [
            nn.Conv2d((4 if c.occupancy else 2) * c.fold * c.fold, c.pointwise, 1, bias=False),
            nn.BatchNorm2d(c.pointwise),
            nn.ReLU(inplace=True),
        ]
        self.features, width = _stack(stem, c.pointwise, c.channels)
        extra = (2 * c.inliers + 2 * c.spread) if c.figures else 0
        self.head = _PooledHead(width, c.hidden, c.dropout, extra=extra)
        self.blind = _PooledHead(width, c.hidden, c.dropout) if c.blind and extra else None

    def forward(self, x: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        """Takes (B, 2, S, S) VGMs, or the same already folded and lifted to
        (B, 2·f², S/f, S/f) as ``features.vgm_batch(..., fold, lift)`` writes it (lifting only
        the occupied cells costs nothing; a dense ``pow`` costs a millisecond a pair), and,
        when built with ``figures``, (B, 2) matcher figures."""
        if x.shape[1] == 2:
            x = x.clamp(min=0.0)
            if self.occupancy:
                x = torch.cat([x.pow(self.lift), (x > 0).to(x.dtype)], dim=1)
            else:
                x = x.pow(self.lift)
            x = self.fold(x)
        return self._heads(self.features(x), extra)

    def _heads(self, x: torch.Tensor, extra: torch.Tensor | None) -> torch.Tensor:
        """The logit; with a ``blind`` head, the mean of both heads' in eval, and in training
        both (B, 2), so that each head is fitted on its own (``fitting.train_step``)."""
        logit: torch.Tensor = self.head(x, extra)
        if self.blind is None:
            return logit
        both = torch.stack([logit, self.blind(x)], dim=1)
        return both if self.training else both.mean(dim=1)

    def forward_cells(
        self,
        batch: int,
        side: int,
        index: torch.Tensor,
        channel: torch.Tensor,
        value: torch.Tensor,
        extra: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``forward`` on a folded, lifted batch given by its occupied cells alone.

        The stem is a 1×1 convolution and a batch norm, so at an empty folded position its
        output is one constant vector; about 97% of the positions are empty. So the stem is
        computed at the occupied positions only, and the first strided block as the
        convolution of that constant field (one small image) plus each occupied position's
        difference from it: the two dense passes that cost most on a CPU (forward and, in
        training, backward) are never made. In training the stem's batch statistics are
        those of the whole dense batch, the empty positions counted in closed form.

        Args:
            batch: Pairs in the batch.
            side: Folded grid side.
            index: Each occupied cell's pair·side² + folded position.
            channel: Each occupied cell's folded channel.
            value: Each occupied cell's (lifted) value.
            extra: The matcher's figures, when built with ``figures``.
        """
        rows, at = torch.unique(index, return_inverse=True)
        if self.training:
            occupied, empty = self._stem_training(
                batch * side * side, len(rows), at, channel, value
            )
        else:
            occupied, empty = self._stem_eval(len(rows), at, channel, value)
        first = self.features[3]
        assert isinstance(first, nn.Sequential)
        x = sparse_block(first, batch, side, rows, occupied - empty, empty)
        return self._heads(self.features[4:](x), extra)

    def _stem_eval(
        self, rows: int, at: torch.Tensor, channel: torch.Tensor, value: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The stem's output at the occupied positions and at an empty one, batch norm's
        running statistics folded into one affine map."""
        weight, shift = self._stem_affine()
        if weight.device.type == "cpu":
            # The occupied cells as a sparse (positions × channels) matrix times the stem's
            # weights: scipy's CSR product is ~7× faster on two cores than torch's index_add_.
            cells = csr_matrix(
                (value.detach().numpy(), (at.numpy(), channel.numpy())),
                shape=(rows, weight.shape[0]),
            )
            pre = torch.from_numpy(np.asarray(cells @ weight.detach().numpy())) + shift
        else:
            pre = shift.expand(rows, -1).clone()
            pre.index_add_(0, at, value[:, None] * weight[channel])
        return torch.relu(pre), torch.relu(shift)

    def _stem_training(
        self,
        positions: int,
        rows: int,
        at: torch.Tensor,
        channel: torch.Tensor,
        value: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """As ``_stem_eval``, normalised by the batch's statistics over all ``positions``
        (empty ones included, where the convolution's output is its bias), which also move
        batch norm's running averages as ``nn.BatchNorm2d`` would."""
        conv, norm = self.features[0], self.features[1]
        assert isinstance(conv, nn.Conv2d) and isinstance(norm, nn.BatchNorm2d)
        pre = pointwise_at_cells(conv, rows, at, channel, value)
        bias = conv.bias if conv.bias is not None else conv.weight.new_zeros(conv.out_channels)
        # Sums in float64: E[x²] − E[x]² over ~10⁵ positions loses float32's digits.
        blank = positions - rows
        pre64, bias64 = pre.double(), bias.double()
        mean = (pre64.sum(0) + blank * bias64) / positions
        var = (pre64.pow(2).sum(0) + blank * bias64.pow(2)) / positions - mean.pow(2)
        var = var.clamp(min=0.0)
        update_running_stats(norm, mean.detach(), var.detach(), positions)
        scale = norm.weight / torch.sqrt(var.float() + norm.eps)
        occupied = (pre - mean.float()) * scale + norm.bias
        empty = (bias - mean.float()) * scale + norm.bias
        return torch.relu(occupied), torch.relu(empty)

    def _stem_affine(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The stem's 1×1 convolution and batch norm as (C_in, C_out) weights and a shift."""
        conv, norm = self.features[0], self.features[1]
        assert isinstance(conv, nn.Conv2d)
        weight = conv.weight[:, :, 0, 0].T
        shift = conv.bias if conv.bias is not None else torch.zeros_like(weight[0])
        if isinstance(norm, nn.BatchNorm2d):  # not yet folded in by fuse_batch_norm
            assert norm.running_var is not None and norm.running_mean is not None
            scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)
            weight = weight * scale
            shift = (shift - norm.running_mean) * scale + norm.bias
        return weight, shift


def fuse_batch_norm(net: nn.Module) -> nn.Module:
    """An eval-mode copy of ``net`` with each batch norm folded into the convolution before it.

    The same function to float rounding, one pass over memory fewer per block: for inference.
    """
    fused = copy.deepcopy(net).eval()
    for module in fused.modules():
        if not isinstance(module, nn.Sequential):
            continue
        for k in range(len(module) - 1):
            conv, norm = module[k], module[k + 1]
            if isinstance(conv, nn.Conv2d) and isinstance(norm, nn.BatchNorm2d):
                module[k] = fuse_conv_bn_eval(conv, norm)
                module[k + 1] = nn.Identity()
    return fused


@dataclass(frozen=True)
class RGBConfig:
    """The baseline's CNN, of the paper network's size: four stride-2 convolutions of 32, 64,
    128, 128 filters over the 3×200×200 plot, a 256-unit MLP."""

    image: int = 200
    channels: tuple[int, ...] = (32, 64, 128, 128)
    hidden: int = 256
    dropout: float = 0.3


class RGBNet(nn.Module):
    """CNN over an RGB plot of the matched pair (Jeong and Lee's validation baseline)."""

    def __init__(self, config: RGBConfig | None = None) -> None:
        super().__init__()
        c = config or RGBConfig()
        self.features, width = _stack([], 3, c.channels)
        self.head = _PooledHead(width, c.hidden, c.dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        logit: torch.Tensor = self.head(self.features(x))
        return logit
