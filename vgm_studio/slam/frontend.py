"""The front end: sequential edges between keyframes and loop candidates searched where the
robot may be, each matched, validated, checked for consistency and handed to the running
estimate.

Keyframes are taken a block at a time. For each block the sequential edges are matched from
odometry (against a submap of the last keyframes) and validated together (the validator is
fastest on batches), the running estimate is updated, then every keyframe of the block
proposes loop candidates (``loop_search``: a window that grows with the graph's uncertainty,
and place recognition), those are matched, validated, the ones the validator kept are
checked as a group (``consistency``), and the survivors closed into the graph before the
next block.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.graph.config import GraphConfig
from vgm_studio.graph.pose_graph import GraphEdge, RunningEstimate
from vgm_studio.matching.correlative import CorrelativeConfig, LoopMatcher, SearchWindow
from vgm_studio.matching.descriptor import PlaceIndex
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.submap import Submap
from vgm_studio.progress import counter
from vgm_studio.slam.config import ConsistencyConfig, FrontEndConfig
from vgm_studio.slam.consistency import Loop, consistent
from vgm_studio.slam.edges import WINDOW_SOURCES, SlamEdge, SlamEdgeKind, Validate
from vgm_studio.slam.factors import (
    checked_as,
    drift_edge,
    drift_odometry_edge,
    fallback_edge,
    graph_edge,
    joined_at_match,
    sequential_edge,
)
from vgm_studio.slam.loop_search import (
    Candidate,
    false_loop_pairs,
    place_candidates,
    trail,
    unclosed_candidates,
    window_candidates,
)
from vgm_studio.slam.sequential import SequentialMatcher
from vgm_studio.slam.turned import judge_turned
from vgm_studio.slam.uncertainty import UncertaintyGraph

_T = TypeVar("_T")
# Submaps the front end holds at once (``FrontEnd._match_loops``): a few hundred MB at most.
_SUBMAPS_AT_ONCE = 64


class FrontEnd:
    """Builds the edges of a run over its keyframes.

    Args:
        scans: The keyframes' scans.
        odometry: (K, 3) odometry poses of the keyframes.
        matcher: The scan matcher.
        validate: Sets ``p_success`` and ``kept`` on a block of edges.
        config: Keyframe, loop-search and injection settings.
        graph: Noise floors and robust settings for the running estimate.
        consistency: The group-consistency check of the loops the validator kept.
        loop_bar: The p(success) a loop needs (``EdgeValidator.loop_bar``); a sequential
            match found again over the wide window that says the odometry is off by more
            than the smallest window needs it too (``SequentialMatcher.retry``). None: the
            validator's own word.
    """

    def __init__(
        self,
        scans: Sequence[Scan],
        odometry: NDArray[np.float64],
        matcher: ScanMatcher,
        validate: Validate,
        config: FrontEndConfig,
        graph: GraphConfig,
        consistency: ConsistencyConfig | None = None,
        loop_bar: float | None = None,
    ) -> None:
        self.scans = scans
        self.loop_bar = loop_bar
        self.odometry = odometry
        self.matcher = matcher
        self.validate = validate
        self.config = config
        self.graph = graph
        self.consistency = consistency or ConsistencyConfig()
        # Windows from a scan matcher's drift; the consistency check from the graph's own
        # (wider) covariances, so that it vetoes only what the graph is sure of.
        self._uncertainty = UncertaintyGraph()
        self._graph_uncertainty = UncertaintyGraph()
        # Each keyframe described twice: by its scan (a place reached from any direction)
        # and by its trail (a place reached along the same path, told apart from its look-
        # alikes by the path); see ``_place_candidates``.
        self._places = PlaceIndex()
        self._trails = PlaceIndex()
        self.loop_matcher = LoopMatcher(CorrelativeConfig(min_score=config.loop_min_score))
        self._submaps: dict[tuple[int, int, int], Submap] = {}
        self._sequential_matcher = SequentialMatcher(
            scans, odometry, matcher, self.loop_matcher, config
        )
        self._threads = config.match_threads()
        self._pool: ThreadPoolExecutor | None = None
        self.estimate = RunningEstimate(odometry[0], graph)
        self.edges: list[SlamEdge] = []
        self._checks = 0  # consistency checks made: each one's loops share a group
        self._false = false_loop_pairs(odometry, config) if config.false_loops else {}
        # Keyframe → the estimate its loop search read (the final sweep's baseline): a copy
        # per block, about 1 MB over Intel's 1,496 keyframes, growing with the run's square.
        self._searched: dict[int, NDArray[np.float64]] = {}
        self._noise = np.random.default_rng([config.seed, 3])

    def run(self, progress: bool = True, arrivals: Iterable[int] = ()) -> list[SlamEdge]:
        """Matches and validates every edge; ``self.estimate`` ends with the kept ones.

        ``arrivals``: where the keyframes are still being made (``odometry_stream``), how
        many are ready, after each chunk; a block is taken once all of its keyframes are, the
        last ones once ``arrivals`` ends. The blocks are those of a run given all at once.
        """
        bar = counter(None, "front end", "keyframe", enabled=progress)
        bar.update(1)
        start, size = 1, self.config.block
        with ThreadPoolExecutor(self._threads, thread_name_prefix="loops") as self._pool:
            for known in itertools.chain(arrivals, [None]):
                last = known is None
                if known is None:
                    known = len(self.scans)
                    bar.set_total(known)
                while start < known and (last or start + size <= known):
                    block = range(start, min(start + size, known))
                    self._sequential(block)
                    self._loops(block)
                    start = block.stop
                    bar.update(len(block))
                    bar.set_postfix(
                        loops=sum(e.kind == "loop" for e in self.edges),
                        kept=sum(e.kind == "loop" and e.kept for e in self.edges),
                    )
            if self.config.final_sweep:
                bar.set_description("front end, final sweep")
                self._sweep()
        self._pool = None
        bar.close()
        return self.edges

    def _map(self, fn: Callable[[Candidate], _T], items: Sequence[Candidate]) -> list[_T]:
        if self._pool is None or len(items) < 2:
            return [fn(c) for c in items]
        return list(self._pool.map(fn, items))

    def _match(
        self,
        kind: SlamEdgeKind,
        a: int,
        b: int,
        guess: NDArray[np.float64],
        injected: bool = False,
    ) -> SlamEdge:
        result = self.matcher.match(self.scans[a], self.scans[b], guess)
        return SlamEdge(kind, a, b, guess, result, injected)

    def _sequential(self, block: range) -> None:
        odo, cfg = self.odometry, self.config
        if self.config.sequential_submap > 0:
            edges = self._sequential_matcher.match(block, self.estimate.poses)
        else:
            edges = [
                self._match("sequential", k - 1, k, se2.between(odo[k - 1], odo[k])) for k in block
            ]
        self._validate_measured(edges)
        if self.config.sequential_slide_check and self.config.sequential_submap > 0:
            self._sequential_matcher.check_slides(edges)
        if self.config.sequential_retry and self.config.sequential_submap > 0:
            self._sequential_matcher.retry(edges, self.validate, self.loop_bar)
        for e in edges:
            if e.kept:
                factor = sequential_edge(e, odo, self.graph, cfg)
            else:
                factor = fallback_edge(e, odo, self.graph, cfg)
                e.at_match = joined_at_match(e, cfg)
            self.estimate.add_keyframe(se2.compose(self.estimate.poses[e.a], factor.measurement))
            self.estimate.add_edge(factor)
            self._uncertainty.add(
                drift_edge(e, self.graph, cfg)
                if e.kept
                else drift_odometry_edge(e, odo, self.graph, cfg)
            )
            self._graph_uncertainty.add(self._checked_as(e, factor))
        self.edges.extend(edges)
        self.estimate.update()

    def _validate_measured(self, edges: list[SlamEdge]) -> None:
        """Validates ``edges``; one whose match failed stays out whatever the validator says:
        a failed match returns its guess, no measurement (a loop no pose scored; a step with
        no match, ``SequentialMatcher._pairwise``, which its odometry joins)."""
        self.validate(edges)
        for e in edges:
            e.kept = e.validated = e.kept and e.match.covariance is not None

    def _loops(self, block: range) -> None:
        poses = self.estimate.poses.copy()
        self._searched.update(dict.fromkeys(block, poses))
        candidates = window_candidates(block, poses, self._uncertainty, self.config)
        # Place recognition where the window search cannot be trusted to hold the place: no
        # candidate, or a window clamped smaller than the drift (a revisit the estimate has
        # lost track of). Where the window covers the drift it spares many wide searches.
        cfg = self.config
        proposed = {c.b for c in candidates}
        covered = {c.b for c in candidates if c.covers}
        drifted = [b for b in block if b in proposed and b not in covered]
        unseen = [b for b in block if b not in proposed]
        # Each trail once: queried here, added to the index below, at the same estimate.
        reach = cfg.place_trail
        trails = {b: trail(b, self.scans, poses, reach) for b in block} if reach > 0 else {}
        candidates += self._place_candidates(unseen, cfg.place_candidates, trails)
        candidates += self._place_candidates(drifted, cfg.place_candidates_drifted, trails)
        candidates += self._injected(block)
        self._close(candidates, poses)
        for b in block:
            self._places.add(b, self.scans[b].points())
            if trails:
                self._trails.add(b, trails[b])

    def _sweep(self) -> None:
        """The revisits the run never closed, searched once more from the final estimate
        (``loop_search.unclosed_candidates``)."""
        closed = np.array(
            [(e.a, e.b) for e in self.edges if e.kind == "loop" and e.kept], dtype=np.int64
        )
        poses = self.estimate.poses
        found = unclosed_candidates(closed, poses, self._uncertainty, self.config, self._searched)
        self._close([dataclasses.replace(c, source="sweep") for c in found], poses)

    def _close(self, candidates: list[Candidate], poses: NDArray[np.float64]) -> None:
        """Matches, validates and checks ``candidates``, and adds the loops kept."""
        edges = self._match_loops(candidates)
        self._validate_measured(edges)
        if self.loop_bar is not None:
            judge_turned(edges, self._submap, self.scans, poses, self.config, self.loop_matcher)
        self._check_consistency([e for e in edges if e.kept], poses)
        kept = [e for e in edges if e.kept]
        for e in kept:
            self._add(graph_edge(e, self.graph))
        self.edges.extend(edges)
        if kept:
            self.estimate.update(extra_iterations=2)

    def _match_loops(self, candidates: list[Candidate]) -> list[SlamEdge]:
        """Each candidate matched on its submap, ``_SUBMAPS_AT_ONCE`` submaps held at a time.

        A submap's grids at every branch-and-bound level take megabytes: the final sweep's
        candidates, spread over the whole building, held 6 GB of them on freiburg-campus.
        Submaps first (shared by candidates), then the matches, both on every thread: the
        searches are numpy gathers that release the GIL, and each match is independent.
        """
        groups: dict[tuple[int, int, int], list[int]] = {}
        for i, c in enumerate(candidates):
            groups.setdefault(self._submap_key(c.a, c.b), []).append(i)
        keys = list(groups)
        edges: dict[int, SlamEdge] = {}
        for start in range(0, len(keys), _SUBMAPS_AT_ONCE):
            chunk = [groups[k] for k in keys[start : start + _SUBMAPS_AT_ONCE]]
            # Submaps are placed by the estimate, which moves when loops close: none is kept
            # from an earlier call, and none evicted while the threads build this chunk's.
            self._submaps.clear()
            self._map(lambda c: self._submap(c.a, c.b), [candidates[g[0]] for g in chunk])
            order = [i for g in chunk for i in g]
            matched = self._map(self._match_loop, [candidates[i] for i in order])
            edges.update(zip(order, matched, strict=True))
        return [edges[i] for i in range(len(candidates))]

    def _scan(self, k: int) -> NDArray[np.float64]:
        return self.scans[k].points()

    def _place_candidates(
        self, keyframes: list[int], count: int, trails: dict[int, NDArray[np.float64]]
    ) -> list[Candidate]:
        """Place candidates of ``keyframes`` by their scans and by their ``trails`` (none
        when ``place_trail`` is 0), each pair once.

        A trail tells a corridor's look-alike places apart (CSAIL: the right place first 1.7×
        as often), but only where the robot came the same way; a scan also finds a place
        reached from another direction (at junctions: on Intel, FHW and Freiburg 101 the scan
        alone ranks the right place among the first five as often or more often).
        """
        out = place_candidates(keyframes, self._places, self._scan, self.config, count)
        if trails:
            seen = {(c.a, c.b) for c in out}
            more = place_candidates(keyframes, self._trails, trails.__getitem__, self.config, count)
            out += [c for c in more if (c.a, c.b) not in seen]
        return out

    def _injected(self, block: range) -> list[Candidate]:
        out = []
        linear, angular = self.config.window_linear[0], math.radians(self.config.place_angular_deg)
        for b in block:
            for a in self._false.get(b, []):
                # A place-recognition false positive: "b is where a was", give or take.
                guess = self._noise.normal(size=3) * [0.3, 0.3, math.radians(5.0)]
                out.append(Candidate(a, b, "injected", guess, linear, angular))
        return out

    def _match_loop(self, c: Candidate) -> SlamEdge:
        """Matches b against a submap of the keyframes around a, over the candidate's window.

        A window candidate is first matched in the smallest window around the estimate; the
        full window's pose replaces it only if it scores clearly higher.
        """
        submap = self._submap(c.a, c.b)
        target, scan = self.scans[c.a], self.scans[c.b]
        cfg = self.config
        wide = SearchWindow(c.linear, c.angular)
        small = SearchWindow(cfg.window_linear[0], math.radians(cfg.window_angular_deg[0]))
        by_window = c.source in WINDOW_SOURCES
        if not by_window or (c.linear <= small.linear and c.angular <= small.angular):
            result = self.loop_matcher.match(submap, target, scan, c.guess, wide)
        else:
            result = self.loop_matcher.match(submap, target, scan, c.guess, small)
            bar = (1.0 + cfg.prefer_estimate) * (result.score or 0.0)
            # Scores are at most 1: past that bar the wide window cannot win, and below it
            # branch and bound may drop every pose that would not (same answer, less work).
            if bar < 1.0:
                floor = max(self.loop_matcher.config.min_score, bar)
                far = self.loop_matcher.match(submap, target, scan, c.guess, wide, floor)
                if (far.score or 0.0) > bar:
                    result = far
        injected = c.source == "injected"
        return SlamEdge("loop", c.a, c.b, c.guess, result, injected, source=c.source, reach=c.reach)

    def _submap_key(self, a: int, b: int) -> tuple[int, int, int]:
        # Keyframes near b would match b trivially; the submap stays well before it.
        last = max(a, min(a + self.config.submap_keyframes, b - self.config.loop_min_gap))
        return (a, max(0, a - self.config.submap_keyframes), last + 1)

    def _submap(self, a: int, b: int) -> Submap:
        key = self._submap_key(a, b)
        if key not in self._submaps:
            if len(self._submaps) >= _SUBMAPS_AT_ONCE:  # never within a chunk of _match_loops
                del self._submaps[next(iter(self._submaps))]
            members = range(key[1], key[2])
            poses = se2.between(self.estimate.poses[a], self.estimate.poses[members])
            self._submaps[key] = Submap.from_scans([self.scans[k] for k in members], poses)
        return self._submaps[key]

    def _check_consistency(self, loops: list[SlamEdge], poses: NDArray[np.float64]) -> None:
        if not self.consistency.enabled or not loops:
            return
        checked = [
            Loop(
                e.a,
                e.b,
                e.estimate,
                graph_edge(e, self.graph).covariance,
                surprise=e.source == "place" or not math.isnan(e.overlap),
            )
            for e in loops
        ]
        flags = consistent(
            checked, poses, self._graph_uncertainty, self.consistency, drift=self._uncertainty
        )
        for e, ok in zip(loops, flags, strict=True):
            e.consistency = "kept" if ok else "rejected"
            e.kept = bool(ok)
            e.group = self._checks
        self._checks += 1

    def _checked_as(self, edge: SlamEdge, factor: GraphEdge) -> GraphEdge:
        inside = self._sequential_matcher.inside(edge)
        return checked_as(edge, factor, self.odometry, self.graph, self.loop_bar, inside)

    def _add(self, factor: GraphEdge) -> None:
        self.estimate.add_edge(factor)
        self._uncertainty.add(factor)
        self._graph_uncertainty.add(factor)
