"""Sequential edges: each keyframe matched against a submap of the last ones, and matched
again over a wide window where the validator rejected it.

A block's keyframes are not in the running estimate yet, so their submaps are placed by
chaining the block's own matches. A wrong match therefore also misplaces the keyframe in the
next one's submap; the second search chains the wide matches it finds, so that a keyframe
after a wrong one is searched against a submap that holds together (Belgioioso keyframes
300–302: the odometry 47° off at one keyframe, the wide match of the first step right, that
of the second lost against a submap turned by the first's wrong match).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.correlative import LoopMatcher, SearchWindow
from vgm_studio.matching.matcher import MatchResult, ScanMatcher
from vgm_studio.matching.submap import Submap
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import SlamEdge, Validate
from vgm_studio.slam.factors import held_step

Poses = dict[int, NDArray[np.float64]]


class SequentialMatcher:
    """Matches a block's sequential edges and searches the rejected ones again.

    Args:
        scans: The keyframes' scans.
        odometry: (K, 3) odometry poses of the keyframes.
        matcher: The pairwise matcher, for a scan the submap search finds nothing for.
        loop_matcher: The correlative matcher.
        config: The submap size and the windows.
    """

    def __init__(
        self,
        scans: Sequence[Scan],
        odometry: NDArray[np.float64],
        matcher: ScanMatcher,
        loop_matcher: LoopMatcher,
        config: FrontEndConfig,
    ) -> None:
        self.scans, self.odometry, self.config = scans, odometry, config
        self.matcher, self.loop_matcher = matcher, loop_matcher
        self._start: Poses = {}
        self._submaps: dict[int, Submap] = {}
        self._small_window = SearchWindow(
            config.window_linear[0], math.radians(config.window_angular_deg[0])
        )
        self._wide_window = SearchWindow(
            config.window_linear[1], math.radians(config.sequential_wide_angular_deg)
        )

    def match(self, block: range, estimate: NDArray[np.float64]) -> list[SlamEdge]:
        """Each keyframe of ``block`` against a submap of the last ones, in the frame of the
        one before it, from the odometry's step within the smallest loop window.

        Args:
            block: The keyframes to match, each to the one before it.
            estimate: The running estimate of the keyframes before the block.
        """
        first = max(0, block.start - self.config.sequential_submap)
        self._start = {k: estimate[k] for k in range(first, block.start)}
        poses = dict(self._start)
        self._submaps.clear()
        edges = []
        for k in block:
            submap = self._submap(k, poses)
            self._submaps[k] = submap
            guess = se2.between(self.odometry[k - 1], self.odometry[k])
            result = self.loop_matcher.match(
                submap, self.scans[k - 1], self.scans[k], guess, self._small_window
            )
            if result.covariance is None:
                # Nothing scored (a scan that sees little): the pairwise matcher's answer.
                result = self._pairwise(submap, k, guess, result)
            edges.append(SlamEdge("sequential", k - 1, k, guess, result))
            poses[k] = se2.compose(poses[k - 1], edges[-1].estimate)
        return edges

    def _pairwise(
        self, submap: Submap, k: int, guess: NDArray[np.float64], failed: MatchResult
    ) -> MatchResult:
        """The pairwise matcher's answer for keyframe k, where the submap search scored
        nothing; ``failed`` (no match) where the answer lies outside the smallest window and
        the submap does not score it ``sequential_pairwise_gain`` above the odometry's
        step."""
        answer = self.matcher.match(self.scans[k - 1], self.scans[k], guess)
        gain = self.config.sequential_pairwise_gain
        if gain is None or self.inside(SlamEdge("sequential", k - 1, k, guess, answer)):
            return answer
        near_answer = self._best_score(submap, k, answer.estimate)
        near_odometry = self._best_score(submap, k, guess)
        return answer if near_answer >= near_odometry + gain else failed

    def _best_score(self, submap: Submap, k: int, centre: NDArray[np.float64]) -> float:
        """The submap's best score of keyframe k in the smallest window around ``centre``,
        however low."""
        hit = self.loop_matcher.search(submap, self.scans[k], centre, self._small_window, 0.0)
        return 0.0 if hit is None else hit.score

    def check_slides(self, edges: list[SlamEdge]) -> None:
        """Kept matches that ended further from the odometry than the window they were
        searched in reaches in x or y, checked against the odometry by a match across two
        steps, this one and a neighbour: where that match lies nearer the odometry's step
        than the match's, the match goes out (``consistency: rejected``; the validator's own
        word stays in ``validated``).

        The neighbour is a kept match inside its window where there is one, else one the
        validator rejected, which the graph joins by its odometry step (or its match, where the
        validator was only unsure: ``factors.held_step``); without that, a slid
        match between two rejected steps had no referee (freiburg-campus keyframe 177: the
        pairwise matcher's answer 1.25 m off at p 0.35, with the wheels 0.18 m off; 0.101 →
        0.092 m).

        The correlative search covers the small window around the odometry's step; a match
        outside it was carried there by the refinement, or found by the pairwise matcher
        where the search scored nothing. Along open walls a point-to-line fit can walk on
        from one nearest neighbour to the next, and the pair still looks right to the
        validator (freiburg-campus keyframes 1096–1097: the search 0.06 m off, the refined
        match 0.55 m off, p 0.96, with the wheel odometry 0.05 m off). Where instead the
        odometry is off by more than the window, the match across agrees with the match (a
        search of its own neighbourhood alone did worse: Belgioioso 0.052 → 0.060 m).
        """
        for i, e in enumerate(edges):
            if not e.kept or not self._slid(e):
                continue
            near = [n for n in (i + 1, i - 1) if 0 <= n < len(edges)]
            inside = (n for n in near if edges[n].kept and self.inside(edges[n]))
            j = next(inside, next((n for n in near if not edges[n].kept), None))
            if j is None:
                continue
            a, c = edges[min(i, j)].a, edges[max(i, j)].b
            # The neighbour's step as the graph will hold it.
            theirs = held_step(edges[j], self.config)
            matched = _two_steps(i, j, e.estimate, theirs)
            odometry = _two_steps(i, j, e.guess, theirs)
            # The block's submaps still hold as matched: each placed by the matches before it.
            across = self._across(self._submaps[a + 1], a, c, (matched, odometry))
            if across is not None and _gap(across, odometry) < _gap(across, matched):
                e.kept, e.consistency = False, "rejected"

    def _slid(self, edge: SlamEdge) -> bool:
        """Whether a match moved further from its odometry step than the smallest window's
        half-width. Only the translation counts: a refinement walks along walls, not round
        them, and a match turned out of the window is one whose odometry turned wrong (the
        infinite corridor's keyframe 863: the odometry 14° off, the match right, and the match
        across two steps, in a corridor, nearer the odometry)."""
        linear, _ = edge.offset()
        return linear > self._small_window.linear

    def inside(self, edge: SlamEdge) -> bool:
        """Whether a match lies in the smallest window around its odometry step."""
        return edge.within(self._small_window.linear, self._small_window.angular)

    def retry(
        self, edges: list[SlamEdge], validate: Validate, loop_bar: float | None = None
    ) -> None:
        """Sequential edges the validator rejected, matched again over the wide window; a
        wide match that the validator keeps takes the rejected one's place.

        The validator, not a fixed inlier share, says which matches are poor: the share a
        right match keeps depends on the scanner and the building (median 0.8 on CSAIL,
        0.5 on Acapulco), and the validator was trained on exactly these figures.

        A wide match outside the smallest window around its odometry step says the odometry
        is wrong by more than it drifts: a surprise, like a loop, and one wrong step bends
        the rest of the chain as a false loop would. It must reach ``loop_bar`` too (None:
        the validator's word alone). Where a robot turns a corner, the submap behind it
        holds little of what the new scan sees, and the wide window holds a pose that fits
        that little better than the right one (CSAIL keyframes 52–53: 2.6 m sideways from
        the wheels' step at p 0.72, the map 0.18 m off where it would be 0.10).
        """
        retried: dict[int, SlamEdge] = {}
        poses = dict(self._start)
        for i, e in enumerate(edges):
            if not e.kept:
                # After a step searched again, the submap is placed by that step's new match.
                submap = self._submap(e.b, poses) if retried else self._submaps[e.b]
                small = self._small(submap, e) if retried else e.match
                wide = self._wider(submap, e.b, e.guess, small)
                if wide is not e.match:
                    retried[i] = SlamEdge("sequential", e.a, e.b, e.guess, wide)
            poses[e.b] = se2.compose(poses[e.a], retried.get(i, e).estimate)
        if not retried:
            return
        validate(list(retried.values()))
        for i, r in retried.items():
            edges[i].wide_kept = r.kept
        kept = {i: r for i, r in retried.items() if r.kept and self._believed(r, loop_bar)}
        while lone := [i for i in kept if not self._bridged(i, edges, kept, poses)]:
            for i in lone:
                del kept[i]
        for i, r in kept.items():
            edges[i] = r

    def _bridged(
        self, i: int, edges: list[SlamEdge], kept: dict[int, SlamEdge], poses: Poses
    ) -> bool:
        """Whether wide match i may go in beside its neighbours: a third match, of the
        keyframes either side of two steps, must agree with it rather than with the odometry.

        Next to a step left to the odometry, always. Where the odometry is wrong at one
        keyframe only (a scan stamped mid-turn), its error cancels over the two steps that
        keyframe joins; a matched step next to an odometry step would keep it (Belgioioso
        keyframes 73–75: a right match the validator doubted, p 0.25, left the next step's
        right wide match out, and its odometry, 38° off, in).

        Between matched steps, where the wide match lies outside the smallest window around
        its odometry step: it then says the odometry is wrong, and one wrong step turns the
        rest of the chain, which no loop can mend once the estimate is sure of it (fhw
        keyframes 55–56, a robot turning on the spot: wheels and kiss-icp agree on +78°, the
        wide search around standing still found −15° at p 0.79; the map ended 1.1 m off).
        """
        checked = [j for j in (i - 1, i + 1) if self._odometry_neighbour(j, edges, kept)]
        if not checked and not self.inside(kept[i]):
            checked = [j for j in (i + 1, i - 1) if 0 <= j < len(edges)][:1]
        for j in checked:
            a, c = edges[min(i, j)].a, edges[max(i, j)].b
            # The neighbour's step as the graph will hold it.
            if self._odometry_neighbour(j, edges, kept):
                theirs = held_step(edges[j], self.config)
            else:
                theirs = kept[j].estimate if j in kept else edges[j].estimate
            with_match = _two_steps(i, j, kept[i].estimate, theirs)
            odometry = _two_steps(i, j, kept[i].guess, theirs)
            across = self._across(self._submap(a + 1, poses), a, c, (with_match, odometry))
            if across is None or _gap(across, with_match) >= _gap(across, odometry):
                return False
        return True

    def _believed(self, wide: SlamEdge, loop_bar: float | None) -> bool:
        """Whether a kept wide match may say the odometry is wrong: it lies inside the
        smallest window around the odometry's step, or its p reaches the loop bar."""
        return loop_bar is None or self.inside(wide) or wide.p_success >= loop_bar

    @staticmethod
    def _odometry_neighbour(j: int, edges: list[SlamEdge], kept: dict[int, SlamEdge]) -> bool:
        """Whether step j exists and stays rejected: the graph joins it by its odometry, or at
        its match where the validator was only unsure (``factors.held_step``)."""
        return 0 <= j < len(edges) and not edges[j].kept and j not in kept

    def _across(
        self, submap: Submap, a: int, c: int, centres: tuple[NDArray[np.float64], ...]
    ) -> NDArray[np.float64] | None:
        """Keyframe c matched against ``submap`` (the keyframes up to a, in a's frame), over
        the wide window around each centre: the best-scoring estimate, None where none
        scores."""
        found = [
            self.loop_matcher.match(submap, self.scans[a], self.scans[c], centre, self._wide_window)
            for centre in centres
        ]
        scored = [m for m in found if m.covariance is not None]
        if not scored:
            return None
        return np.asarray(max(scored, key=lambda m: m.score or 0.0).estimate, dtype=np.float64)

    def _submap(self, k: int, poses: Poses) -> Submap:
        """The last keyframes before k, placed by ``poses`` in the frame of k - 1."""
        members = range(max(0, k - self.config.sequential_submap), k)
        local = se2.between(poses[k - 1], np.array([poses[j] for j in members]))
        return Submap.from_scans([self.scans[j] for j in members], local)

    def _small(self, submap: Submap, edge: SlamEdge) -> MatchResult:
        """``edge`` matched again in the smallest window, against a submap placed anew; the
        first match where this one scores nothing."""
        again = self.loop_matcher.match(
            submap, self.scans[edge.a], self.scans[edge.b], edge.guess, self._small_window
        )
        return again if again.covariance is not None else edge.match

    def _wider(
        self, submap: Submap, k: int, guess: NDArray[np.float64], small: MatchResult
    ) -> MatchResult:
        """Keyframe k matched again over the wide window, around the odometry's step and
        around standing still; ``small`` itself unless one of them is clearly better.

        A rejected small-window match often means the odometry's step is off by more than
        the small window (kiss-icp lost, wheels slipping). A lost odometry can be off by more
        than the wide window too (kiss-icp carrying a wrong speed down a corridor), but the
        robot itself rarely moves more than the wide window between keyframes, so the window
        around standing still holds the true step whatever the odometry says. A wide match
        must put clearly more of the scan on the keyframe than the small one: along a
        corridor the wide window holds poses that fit nearly as well as the right one.
        """
        best = small
        gain = self.config.sequential_retry_gain
        bar = small.inlier_ratio + gain if small.covariance is not None else 0
        for centre in (guess, np.zeros(3)):
            far = self.loop_matcher.match(
                submap, self.scans[k - 1], self.scans[k], centre, self._wide_window
            )
            if far.covariance is not None and far.inlier_ratio >= bar:
                best, bar = far, far.inlier_ratio
        return best


def _two_steps(
    i: int, j: int, mine: NDArray[np.float64], theirs: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The relative pose across the neighbouring steps i and j, with step i taken as
    ``mine`` and step j as ``theirs``, composed in keyframe order."""
    return se2.compose(mine, theirs) if i < j else se2.compose(theirs, mine)


def _gap(p: NDArray[np.float64], q: NDArray[np.float64]) -> float:
    """How far two relative poses are apart: metres plus radians (keyframes sit about a metre
    apart, so a radian there moves the next one by about a metre)."""
    d = se2.between(p, q)
    return float(math.hypot(d[0], d[1]) + abs(d[2]))
