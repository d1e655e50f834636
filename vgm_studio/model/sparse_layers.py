"""Layers of ``VGMNet`` evaluated on the occupied cells of a mostly empty VGM: a 1×1
convolution at the occupied positions, a strided block as the convolution of a constant field
plus each occupied position's difference from it, and batch norm's running statistics moved as
``nn.BatchNorm2d`` would over the whole dense batch."""

from __future__ import annotations

import torch
from torch import nn


def pointwise_at_cells(
    conv: nn.Conv2d, rows: int, at: torch.Tensor, channel: torch.Tensor, value: torch.Tensor
) -> torch.Tensor:
    """A 1×1 convolution's output (bias included) at ``rows`` occupied positions, from their
    cells: cell k is at position ``at[k]``, in input channel ``channel[k]``. Differentiable."""
    cells = conv.weight.new_zeros(rows, conv.in_channels)
    cells.index_put_((at, channel), value.to(cells.dtype), accumulate=True)
    out = cells @ conv.weight[:, :, 0, 0].T
    return out + conv.bias if conv.bias is not None else out


def sparse_block(
    block: nn.Sequential,
    batch: int,
    side: int,
    rows: torch.Tensor,
    delta: torch.Tensor,
    empty: torch.Tensor,
) -> torch.Tensor:
    """A (convolution, norm, activation) block over a field that is ``empty`` everywhere but at
    ``rows`` (pair·side² + position), where it is ``empty + delta``.

    Convolution is linear: its output is the convolution of the constant field (one image,
    borders and all, broadcast over the batch) plus, for each kernel tap, each occupied
    position's ``delta`` times that tap's weights, added where the tap puts it.
    """
    conv = block[0]
    assert isinstance(conv, nn.Conv2d) and conv.groups == 1 and conv.dilation == (1, 1)
    padding = conv.padding
    assert not isinstance(padding, str)  # "same"/"valid" are not used by our blocks
    (kh, kw), (sh, sw), (ph, pw) = conv.kernel_size, conv.stride, padding
    channels = conv.out_channels
    field = empty.view(1, -1, 1, 1).expand(1, -1, side, side)
    base = nn.functional.conv2d(field, conv.weight, conv.bias, conv.stride, conv.padding)
    oh, ow = base.shape[2:]
    out = base.permute(0, 2, 3, 1).repeat(batch, 1, 1, 1).view(-1, channels)  # one copy
    pair, position = rows // (side * side), rows % (side * side)
    i, j = position // side, position % side
    # Where each row tap and each column tap lands (and whether it does), worked out once
    # each instead of once per kernel tap: a 3×3 kernel's nine taps share three of each.
    down, across = [], []
    for ki in range(kh):
        ti = i + ph - ki  # stride × output row, when the tap lands on one
        down.append(((ti % sh == 0) & (ti >= 0) & (ti < sh * oh), pair * oh + ti // sh))
    for kj in range(kw):
        tj = j + pw - kj
        across.append(((tj % sw == 0) & (tj >= 0) & (tj < sw * ow), tj // sw))
    targets, terms = [], []
    for ki, (row_ok, row) in enumerate(down):
        for kj, (col_ok, col) in enumerate(across):
            ok = row_ok & col_ok
            targets.append(row[ok] * ow + col[ok])
            terms.append(delta[ok] @ conv.weight[:, :, ki, kj].T)
    target, term = torch.cat(targets), torch.cat(terms)
    if torch.is_grad_enabled() and term.requires_grad:
        # In training an in-place add would have autograd keep a copy of the whole field.
        out = out.index_add(0, target, term)
    else:
        out.index_add_(0, target, term)
    x = out.view(batch, oh, ow, channels).permute(0, 3, 1, 2)
    result: torch.Tensor = block[2](block[1](x))
    return result


def update_running_stats(
    norm: nn.BatchNorm2d, mean: torch.Tensor, var: torch.Tensor, count: int
) -> None:
    """Moves ``norm``'s running averages by a batch's mean and biased variance over ``count``
    values, as ``nn.BatchNorm2d`` does in training (the running variance is unbiased;
    momentum None is a cumulative average)."""
    if not norm.track_running_stats:
        return
    assert norm.running_mean is not None and norm.running_var is not None
    assert norm.num_batches_tracked is not None
    with torch.no_grad():
        norm.num_batches_tracked.add_(1)
        factor = norm.momentum
        if factor is None:
            factor = 1.0 / float(norm.num_batches_tracked)
        unbiased = var * count / max(count - 1, 1)
        norm.running_mean.mul_(1 - factor).add_(factor * mean.to(norm.running_mean.dtype))
        norm.running_var.mul_(1 - factor).add_(factor * unbiased.to(norm.running_var.dtype))
