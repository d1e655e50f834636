"""Loop candidates from where the robot may be: a window that grows with the graph's
uncertainty, and place recognition that does not trust the estimate at all.

Window: for each new keyframe b, every keyframe a at least ``loop_min_gap`` earlier whose
estimated offset to b is within a Mahalanobis gate of "the same place". The gate's covariance
is the graph's relative uncertainty between a and b (Dijkstra projection, see ``uncertainty``)
plus a disc of radius ``loop_radius`` (the reach at which two scans still overlap), so where
the graph is sure the search is the old fixed radius, and 200 m of unclosed corridor later it
spans metres. The nearest candidates by that distance are matched over a search window of
three σ, clamped.

Place: wherever the window cannot cover three σ (the drift outgrew the widest window) or
finds nothing, the keyframe's descriptors against those of all earlier keyframes (a Scan
Context for 2D lasers, Kim and Kim 2018, in a KD-tree of rotation-invariant ring keys,
re-ranked by the column-shift distance; see ``matching.descriptor``): one of its scan and one
of its trail, the scan and those of the last metres of the path placed by the estimate, which
is sure of a few metres even where it has lost the building. Neither reads where the estimate
puts the keyframe, so a revisit is proposed even tens of metres off. Its window is centred on
the descriptor's yaw.

Sweep: after the run, the window search once more from the final estimate, for the revisits
no kept loop closed (``unclosed_candidates``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.descriptor import PlaceIndex
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import EdgeSource
from vgm_studio.slam.uncertainty import Relative, UncertaintyGraph, chi2_gate

# At most this many scans in a trail: where keyframes are close (a robot turning on the
# spot), a few metres of path would otherwise hold hundreds.
_TRAIL_SCANS = 40


@dataclass(frozen=True)
class Candidate:
    """A loop to match: pose guess of b in a's frame and the window around it.

    Attributes:
        linear: Half-width of the search window in x and y, metres.
        angular: Half-width in heading, radians.
        covers: The window spans three σ of where b may be relative to a. A window clamped
            smaller (the graph has drifted farther than a search can afford) may miss the
            place, so place recognition looks too.
        reach: Three σ of where b may be relative to a, in x and y, metres (window
            candidates; NaN for the others).
    """

    a: int
    b: int
    source: EdgeSource
    guess: NDArray[np.float64]
    linear: float
    angular: float
    covers: bool = True
    reach: float = math.nan


def _clamp(value: float, bounds: tuple[float, float]) -> float:
    return float(min(max(value, bounds[0]), bounds[1]))


def window_candidates(
    block: Sequence[int],
    poses: NDArray[np.float64],
    graph: UncertaintyGraph,
    config: FrontEndConfig,
) -> list[Candidate]:
    """The window candidates of each keyframe of ``block``, nearest (by Mahalanobis) first."""
    keyframes = [b for b in block if b - config.loop_min_gap >= 0]
    if not keyframes or config.loops_per_keyframe == 0:
        return []
    gate = chi2_gate(config.loop_gate, 2)
    # With no uncertainty the gate reaches exactly loop_radius.
    reach_var = config.loop_radius**2 / gate
    out: list[Candidate] = []
    for b, rel in zip(keyframes, graph.relative(keyframes, len(poses)), strict=True):
        out += _window_of(b, poses, rel, gate, reach_var, config)
    return out


def unclosed_candidates(
    closed: NDArray[np.int64],
    poses: NDArray[np.float64],
    graph: UncertaintyGraph,
    config: FrontEndConfig,
    searched: Mapping[int, NDArray[np.float64]] | None = None,
) -> list[Candidate]:
    """Window candidates, on the run's final estimate, of the revisits it never closed.

    A keyframe is searched again where no kept loop ends within ``submap_keyframes`` of it,
    and a candidate a → b is kept where no kept loop joins a's neighbourhood to b's and the
    estimate has since moved b relative to a by more than the smallest window (else the
    search would repeat the one made online). Online, each keyframe was searched once, from
    where the estimate put it then; a revisit met before the loops that straighten the map
    went in was searched in the wrong place. On CSAIL a validator that closed its central
    ring late left the revisits 120–135 ↔ 197–213 open so (0.131 m).

    Args:
        closed: (L, 2) keyframes (a, b) of the loops kept.
        poses: (K, 3) the final estimate.
        graph: The loop search's view of the graph (the drift), loops included.
        config: The window search's settings.
        searched: Keyframe b → the estimate its online search read (None: every candidate
            counts as moved).
    """
    span = config.submap_keyframes
    ends = np.asarray(closed, dtype=np.int64).reshape(-1, 2)
    keyframes = np.arange(len(poses))
    lonely = _farther_than(keyframes, ends[:, 1], span)
    # A block at a time, as online: the projection holds a K-long array per keyframe asked.
    unclosed = keyframes[lonely].tolist()
    found = [
        c
        for start in range(0, len(unclosed), config.block)
        for c in window_candidates(unclosed[start : start + config.block], poses, graph, config)
    ]
    linear, angular = config.window_linear[0], math.radians(config.window_angular_deg[0])

    def moved(c: Candidate) -> bool:
        if searched is None or c.b not in searched:
            return True
        then = searched[c.b]
        change = se2.between(se2.between(then[c.a], then[c.b]), c.guess)
        return bool(math.hypot(change[0], change[1]) > linear or abs(change[2]) > angular)

    return [
        c
        for c in found
        if moved(c)
        and not ((np.abs(ends[:, 0] - c.a) <= span) & (np.abs(ends[:, 1] - c.b) <= span)).any()
    ]


def _farther_than(
    keyframes: NDArray[np.int64], ends: NDArray[np.int64], span: int
) -> NDArray[np.bool_]:
    """Which ``keyframes`` lie more than ``span`` from every one of ``ends``: by the nearest
    end on either side, not a keyframes × ends table (a long log's is gigabytes)."""
    if len(ends) == 0:
        return np.ones(len(keyframes), dtype=bool)
    ends = np.sort(ends)
    right = np.searchsorted(ends, keyframes).clip(max=len(ends) - 1)
    left = (right - 1).clip(min=0)
    nearest = np.minimum(np.abs(ends[left] - keyframes), np.abs(ends[right] - keyframes))
    return np.asarray(nearest > span, dtype=bool)


def _window_of(
    b: int,
    poses: NDArray[np.float64],
    rel: Relative,
    gate: float,
    reach_var: float,
    config: FrontEndConfig,
) -> list[Candidate]:
    olds = np.arange(b - config.loop_min_gap + 1)
    offset = se2.between(poses[olds], poses[b])
    position_var = rel.position_var[olds]
    heading_sigma = np.sqrt(rel.heading_var[olds])
    with np.errstate(invalid="ignore"):
        m2 = (offset[:, 0] ** 2 + offset[:, 1] ** 2) / (position_var + reach_var)
    turn = math.radians(config.loop_max_angle_deg) + 3.0 * heading_sigma
    near = np.isfinite(m2) & (m2 <= gate)
    facing = np.abs(offset[:, 2]) <= turn
    # Each heading class has its own slots: in a corridor the keyframes passed the other way
    # lie nearer than the last same-way pass and would take every slot (Örebro lost its one
    # same-way revisit so, 0.76 → 1.43 m).
    chosen = np.concatenate(
        [
            _nearest(olds, m2, near & facing, config.loops_per_keyframe),
            _nearest(olds, m2, near & ~facing, config.turned_loops_per_keyframe),
        ]
    )
    lo_deg, hi_deg = config.window_angular_deg
    out = []
    for a in chosen:
        reach, turn_deg = 3.0 * math.sqrt(position_var[a]), 3.0 * math.degrees(heading_sigma[a])
        linear = _clamp(reach, config.window_linear)
        angular = _clamp(turn_deg, (lo_deg, hi_deg))
        covers = reach <= linear and turn_deg <= angular
        angle = math.radians(angular)
        out.append(Candidate(int(a), b, "window", offset[a], linear, angle, covers, reach))
    return out


def _nearest(
    olds: NDArray[np.int64], m2: NDArray[np.float64], ok: NDArray[np.bool_], count: int
) -> NDArray[np.int64]:
    return olds[ok][np.argsort(m2[ok], kind="stable")][:count]


def trail(
    k: int, scans: Sequence[Scan], poses: NDArray[np.float64], metres: float
) -> NDArray[np.float64]:
    """Keyframe k's scan and those of the keyframes before it on the last ``metres`` of its
    path, in k's frame, placed by ``poses``: what place recognition describes k by (0: the
    scan alone)."""
    points = [scans[k].points()]
    travelled, j = 0.0, k
    into_k = se2.inverse(poses[k])  # ``between(poses[k], ·)``, its inverse taken once
    while metres > 0 and j > 0 and len(points) < _TRAIL_SCANS:
        travelled += math.dist(poses[j, :2], poses[j - 1, :2])
        if travelled > metres:
            break
        j -= 1
        points.append(se2.transform_points(se2.compose(into_k, poses[j]), scans[j].points()))
    return np.concatenate(points)


def place_candidates(
    keyframes: Sequence[int],
    index: PlaceIndex,
    cloud: Callable[[int], NDArray[np.float64]],
    config: FrontEndConfig,
    per_keyframe: int | None = None,
) -> list[Candidate]:
    """Earlier keyframes whose place looks like that of each of ``keyframes``, whatever the
    estimate.

    ``cloud(k)`` is what keyframe k is described by, in its own frame: its scan, or its trail
    (``FrontEndConfig.place_trail``), as the index holds the earlier ones.

    The guess is "b stands where a stood, turned by the descriptor's yaw"; the window is the
    widest in x and y and ``place_angular_deg`` around that yaw. Pairs turned further than
    ``place_max_angle_deg`` are left out. ``per_keyframe`` nearest descriptors are tried
    (default ``config.place_candidates``).
    """
    count = config.place_candidates if per_keyframe is None else per_keyframe
    if count == 0:
        return []
    out = []
    angular = math.radians(config.place_angular_deg)
    max_turn = math.radians(config.place_max_angle_deg)
    for b in keyframes:
        newest = b - config.loop_min_gap
        if newest < 0:
            continue
        for m in index.query(cloud(b), k=count, max_key=newest):
            if m.distance > config.place_max_distance or abs(m.yaw) > max_turn:
                continue
            guess = np.array([0.0, 0.0, m.yaw])
            out.append(Candidate(m.key, b, "place", guess, config.window_linear[1], angular))
    return out


def false_loop_pairs(odometry: NDArray[np.float64], config: FrontEndConfig) -> dict[int, list[int]]:
    """Keyframe pairs for injected false loops, keyed by the later keyframe.

    Each pair is at least ``loop_min_gap`` keyframes and ``false_loop_distance`` metres
    apart in odometry, so a guess that puts them at one place is wrong by construction.
    """
    rng = np.random.default_rng([config.seed, 2])
    out: dict[int, list[int]] = {}
    count = len(odometry)
    for _ in range(100 * config.false_loops):
        if sum(map(len, out.values())) >= config.false_loops or count <= config.loop_min_gap:
            break
        b = int(rng.integers(config.loop_min_gap, count))
        a = int(rng.integers(0, b - config.loop_min_gap + 1))
        far = math.dist(odometry[a, :2], odometry[b, :2]) >= config.false_loop_distance
        if far and a not in out.get(b, []):
            out.setdefault(b, []).append(a)
    return out
