"""The edges a SLAM run makes: matched keyframe pairs and what validation said of them."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.matching.matcher import MatchResult

SlamEdgeKind = Literal["sequential", "loop"]
# Where a candidate came from: odometry (sequential edges), the uncertainty window around the
# estimate, place recognition, the final sweep on the last estimate, a deliberately false
# loop (``--inject-false-loops``), or another SLAM's graph file (``audit``).
EdgeSource = Literal["odometry", "window", "place", "sweep", "injected", "graph"]
# The sources of real loops, as the JSON, the fleet table and the maps count them.
LOOP_SOURCES: tuple[EdgeSource, ...] = ("window", "place", "sweep")
# Loops searched for around the estimate (online or in the final sweep): matched in the
# smallest window first, and turned ones judged by their local maps.
WINDOW_SOURCES: tuple[EdgeSource, ...] = ("window", "sweep")
Consistency = Literal["kept", "rejected", "not-checked"]


@dataclass
class SlamEdge:
    """A matched pair of keyframes.

    Attributes:
        kind: ``sequential`` (consecutive keyframes) or ``loop``.
        a: Index of the earlier keyframe.
        b: Index of the later keyframe.
        guess: The pose of b in a's frame the matcher started from.
        match: The matcher's result; ``match.estimate`` is the measurement.
        injected: A false loop closure put in on purpose (``--inject-false-loops``).
        p_success: The validator's p(success); NaN when it gives none.
        kept: The edge went into the graph: the validator kept it and the consistency check
            did not reject it.
        source: Where the candidate came from.
        validated: The validator's own decision (``kept`` before the consistency check).
        consistency: The group-consistency check's decision on a loop the validator kept,
            and ``rejected`` on a sequential edge the odometry check of a match that slid
            outside its window took out; else ``not-checked``.
        overlap: Turned loops the validator's network rejected: the share of b's trail that
            lies on a's submap at the estimate (``FrontEndConfig.turned_overlap``); NaN
            where not measured.
        group: The consistency check the loop was judged in (loops checked together share
            it, numbered from 0 in the order the run checked them); None where unchecked.
        reach: A window loop's three σ of where b may be relative to a, metres
            (``Candidate.reach``); NaN for the others.
        wide_kept: A rejected sequential step whose match over the wide window the
            validator kept, adopted or not (``SequentialMatcher.retry``): the odometry is
            then in doubt as well as the step's own match (``factors.fallback_edge``).
        at_match: A rejected sequential step the graph joins at its match, at an odometry's
            σ, the validator having been only unsure of it (``factors.joined_at_match``);
            still counted as rejected.
    """

    kind: SlamEdgeKind
    a: int
    b: int
    guess: NDArray[np.float64]
    match: MatchResult
    injected: bool = False
    p_success: float = math.nan
    kept: bool = True
    source: EdgeSource = "odometry"
    validated: bool = True
    consistency: Consistency = "not-checked"
    overlap: float = math.nan
    group: int | None = None
    reach: float = math.nan
    wide_kept: bool = False
    at_match: bool = False

    @property
    def estimate(self) -> NDArray[np.float64]:
        return np.asarray(self.match.estimate, dtype=np.float64)

    def offset(self) -> tuple[float, float]:
        """How far the match lies from its guess (a sequential edge's: the odometry's step),
        as a search window measures it: the larger of x and y, metres, and the turn, radians."""
        d = self.estimate - self.guess
        return float(max(abs(d[0]), abs(d[1]))), abs(float(se2.wrap_angle(d[2])))

    def within(self, linear: float, angular: float) -> bool:
        """Whether the match lies in the window of these half-widths around its guess."""
        moved, turn = self.offset()
        return moved <= linear and turn <= angular


# Sets ``p_success``, ``validated`` and ``kept`` on a batch of edges.
Validate = Callable[[Sequence[SlamEdge]], None]
