"""Sector cuts: a training augmentation that takes away part of one scan's view.

A right loop between two scans that see little of the same walls looks, on the VGM, much
like a wrong one: cells that only one scan fills. Cutting a sector out of one scan keeps the
match as right (or as wrong) as it was while its scans share less, so a network learns that
a wall one scan does not see is not evidence against the match.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from vgm_studio.model.features import PairSample

# Widths a cut may take, in radians: from a doorway's view lost to half the scan.
WIDEST = np.pi
NARROWEST = np.pi / 3
# A cut that would leave fewer points than this is not made: the pair would be no pair.
FEWEST_LEFT = 20


def cut_sectors(
    samples: Sequence[PairSample], share: float, rng: np.random.Generator
) -> list[PairSample]:
    """Each pair, with probability ``share``, loses one scan's points in one sector.

    The sector is seen from the previous scan's origin (the pair's frame), its middle and its
    width (60–180°) drawn at random, the scan (previous or current) drawn with even odds. Both
    classes are cut alike, so a cut says nothing of the label.

    Args:
        samples: The batch's pairs; none is changed.
        share: Probability in [0, 1] that a pair is cut.
        rng: Where the draws come from (four per pair, cut or not, so a batch's draws do
            not depend on its points).

    Returns:
        The batch, cut pairs replaced by their cut copies.
    """
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"a sector cut's share must lie in [0, 1], not {share}")
    n = len(samples)
    cut = rng.random(n) < share
    middle = rng.uniform(-np.pi, np.pi, n)
    width = rng.uniform(NARROWEST, WIDEST, n)
    which = rng.random(n) < 0.5
    out = list(samples)
    for k in map(int, np.flatnonzero(cut)):
        s = samples[k]
        points = s.prev if which[k] else s.cur
        angle = np.arctan2(points[:, 1], points[:, 0])
        off = np.abs((angle - middle[k] + np.pi) % (2 * np.pi) - np.pi)
        kept = points[off > width[k] / 2]
        if len(kept) < FEWEST_LEFT:
            continue
        out[k] = replace(s, prev=kept) if which[k] else replace(s, cur=kept)
    return out
