"""A whole SLAM run: odometry, keyframes, the front end, and the `before` and `after` graphs."""

from __future__ import annotations

import dataclasses
import itertools
import multiprocessing
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan, ScanLog
from vgm_studio.errors import InputError
from vgm_studio.graph.pose_graph import GraphEdge, OptimizeResult, optimize
from vgm_studio.matching.keyframes import KeyframePicker, select_keyframes
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.progress import counter
from vgm_studio.slam.between import BetweenPlacements, place_between
from vgm_studio.slam.between_stream import STREAM_FROM, BetweenStream
from vgm_studio.slam.config import FrontEndConfig, SlamConfig
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.factors import fallback_edge, kept_edge
from vgm_studio.slam.frontend import FrontEnd
from vgm_studio.slam.odometry import has_wheels, scan_odometry
from vgm_studio.slam.odometry_stream import Chunk, OdometryStream, ready
from vgm_studio.slam.validation import EdgeValidator, LocalMaps, check_loop_precision, pair_judge

MIN_POINTS = 10


@dataclass
class SlamResult:
    """What a run made.

    Attributes:
        keyframes: (K,) scan indices of the keyframes.
        odometry: (N, 3) kiss-icp odometry of every scan.
        edges: Every matched edge, in the order the front end made them.
        running: (K, 3) the front end's last running estimate.
        before: The graph with every measured edge, optimised.
        after: The graph with the validated edges, optimised.
        threshold: The model's p(success) threshold (NaN for ``none`` and ``reference``).
        seconds: Wall time per stage. ``odometry`` runs until its last pose, ``front_end``
            from there: where the odometry streams (``odometry_stream``) the front end ran
            beside it, and this is what it took after.
        isam2_restarts: 1 when the running estimate had to rebuild iSAM2 with QR (see
            ``RunningEstimate.update``), else 0.
        after_edges: The factors ``after`` was optimised over: the kept edges and what stands
            in for each rejected sequential one, its odometry or, where the validator was only
            unsure, its match (``factors.fallback_edge``; a g2o export writes these).
        given: (K, 3) the keyframe poses an audited graph came with: its maps, recording and
            relation errors then start from ``input``, not the odometry.
        loop_bar: The p(success) a loop was held to (``EdgeValidator.loop_bar``: the highest
            of the model's threshold, the loop threshold and the precision cut); None where
            the validator gives no p or the run did not record it.
        between: The scans between keyframes refined onto the keyframes around them
            (``slam.between``); None where the run placed them by odometry alone.
    """

    keyframes: NDArray[np.int64]
    odometry: NDArray[np.float64]
    edges: list[SlamEdge]
    running: NDArray[np.float64]
    before: OptimizeResult
    after: OptimizeResult
    threshold: float = float("nan")
    seconds: dict[str, float] = field(default_factory=dict)
    isam2_restarts: int = 0
    after_edges: list[GraphEdge] = field(default_factory=list)
    given: NDArray[np.float64] | None = None
    loop_bar: float | None = None
    between: BetweenPlacements | None = None

    @property
    def odometry_keyframes(self) -> NDArray[np.float64]:
        return self.odometry[self.keyframes]

    def scan_poses(
        self, keyframe_poses: NDArray[np.float64], refined: bool = True
    ) -> NDArray[np.float64]:
        """(N, 3) poses of every scan, carried by the odometry from the keyframes and, where
        ``refined``, the anchors between them placed by their refinements (``between``)."""
        if not refined or self.between is None:
            return scan_poses(keyframe_poses, self.keyframes, self.odometry)
        anchors, placed = self.between.place(keyframe_poses)
        known = np.concatenate([self.keyframes, anchors])
        order = np.argsort(known, kind="stable")
        poses = np.concatenate([keyframe_poses, placed])[order]
        return scan_poses(poses, known[order], self.odometry)

    @property
    def edges_kept(self) -> int:
        return sum(e.kept for e in self.edges)


def scan_poses(
    keyframe_poses: NDArray[np.float64], keyframes: NDArray[np.int64], odometry: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Carries keyframe poses to every scan with the odometry, spreading the correction.

    Each keyframe's correction (the transform that takes its odometry pose to its estimated
    one) is blended into the scans after it, towards the next keyframe's correction in
    proportion to the odometry travelled, so a scan between two keyframes moves with both
    rather than carrying all the odometry's error since the first. Scans before the first
    keyframe and after the last take its correction alone.
    """
    count = len(odometry)
    owner = np.searchsorted(keyframes, np.arange(count), side="right") - 1
    owner = np.maximum(owner, 0)
    nxt = np.minimum(owner + 1, len(keyframes) - 1)
    corrections = se2.compose(keyframe_poses, se2.inverse(odometry[keyframes]))
    here = se2.compose(corrections[owner], odometry)
    there = se2.compose(corrections[nxt], odometry)
    # The share of the way from one keyframe to the next: by odometry travelled (drift grows
    # with it), by scan count where the robot only turned.
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(odometry[:, :2], axis=0).T))])
    start, end = keyframes[owner], keyframes[nxt]
    by_travel = _share(travelled, start, end)
    by_index = _share(np.arange(count, dtype=np.float64), start, end)
    t = np.clip(np.nan_to_num(np.where(np.isnan(by_travel), by_index, by_travel)), 0.0, 1.0)
    turn = se2.wrap_angle(there[:, 2] - here[:, 2])
    out = here + t[:, None] * (there - here)
    out[:, 2] = se2.wrap_angle(here[:, 2] + t * turn)
    return np.asarray(out, dtype=np.float64)


def _share(
    axis: NDArray[np.float64], start: NDArray[np.int64], end: NDArray[np.int64]
) -> NDArray[np.float64]:
    """How far each scan is from its keyframe ``start`` towards ``end`` along ``axis``; NaN
    where the two keyframes lie at one place on it."""
    span = axis[end] - axis[start]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(span > 1e-6, (axis - axis[start]) / span, np.nan)


def dense_reference(log: ScanLog, odometry: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """A reference pose for every scan, where the log gives one for only some.

    Scans without one take the nearest (by index) scan that has one and the odometry between
    them: a GMapping log keeps one scan in ~15, and over those few scans odometry is exact
    to millimetres.
    """
    has = np.array([s.reference is not None for s in log.scans])
    if not has.any():
        return None
    idx = np.flatnonzero(has)
    ref = np.array([log.scans[i].reference for i in idx], dtype=np.float64)
    scan = np.arange(len(log))
    pos = np.searchsorted(idx, scan)
    lo, hi = np.clip(pos - 1, 0, len(idx) - 1), np.clip(pos, 0, len(idx) - 1)
    near = np.where(np.abs(idx[lo] - scan) <= np.abs(idx[hi] - scan), lo, hi)
    anchor = idx[near]
    return se2.compose(ref[near], se2.between(odometry[anchor], odometry))


def _usable(log: ScanLog) -> NDArray[np.bool_]:
    # A scan's points are its valid beams: counted without placing them.
    return np.array([np.count_nonzero(s.valid()) >= MIN_POINTS for s in log.scans])


def _workers_pay(log: ScanLog, fe: FrontEndConfig) -> bool:
    """Whether the run's workers (``between_stream``, ``odometry_stream``) may start: the run
    may use a second core (not a one-CPU Ray task, nor a process pool's daemonic worker), and
    the log is long enough to repay a worker's start."""
    if len(log) < STREAM_FROM or fe.match_threads() < 2:
        return False
    return not multiprocessing.current_process().daemon


def _between_stream(
    log: ScanLog, usable: NDArray[np.bool_], fe: FrontEndConfig
) -> BetweenStream | None:
    """The worker that refines the anchors while the odometry runs (``_workers_pay``)."""
    if not _workers_pay(log, fe):
        return None
    try:
        return BetweenStream(log.scans, usable, (fe.keyframe_distance, fe.keyframe_angle_deg))
    except (OSError, RuntimeError):  # no processes here (no /dev/shm, a sandbox)
        return None


@dataclass
class _Made:
    """What the odometry and the front end made; ``run``: the front end, its validator and
    its edges. ``odometry_seconds``: from the start until the odometry's last pose."""

    odometry: NDArray[np.float64]
    keyframes: NDArray[np.int64]
    run: tuple[FrontEnd, EdgeValidator, list[SlamEdge]]
    odometry_seconds: float


def _streams(log: ScanLog, config: SlamConfig, fe: FrontEndConfig) -> bool:
    """Whether the odometry is made in a worker while the front end runs
    (``odometry_stream``): for a long log with wheels (without, kiss-icp's lost steps are
    judged by the run's model), where the run may use a second core, and not where the
    validator needs the whole odometry first (``reference``) or false loops are drawn from
    it."""
    if not _workers_pay(log, fe) or fe.false_loops or config.validation.validator == "reference":
        return False
    return has_wheels(log.scans)


def _front_end(
    made: tuple[list[Scan], NDArray[np.float64], EdgeValidator],
    config: SlamConfig,
    fe: FrontEndConfig,
) -> FrontEnd:
    """The front end over (keyframe scans, their odometry, the validator)."""
    scans, odometry, validator = made
    graph, consistency, bar = config.graph, config.consistency, validator.loop_bar
    return FrontEnd(scans, odometry, ScanMatcher(), validator, fe, graph, consistency, bar)


def _front_end_after_odometry(
    log: ScanLog,
    usable: NDArray[np.bool_],
    config: SlamConfig,
    fe: FrontEndConfig,
    on_pose: Callable[[int, NDArray[np.float64]], None] | None,
    progress: bool,
) -> _Made:
    """The odometry of every scan, then the front end over its keyframes."""
    t = time.perf_counter()
    judge = pair_judge(config.validation)
    odometry = scan_odometry(log.scans, progress=progress, judge=judge, on_pose=on_pose)
    odometry_seconds = time.perf_counter() - t
    pool = np.flatnonzero(usable)
    keyframes = pool[select_keyframes(odometry[pool], fe.keyframe_distance, fe.keyframe_angle_deg)]
    scans = [dataclasses.replace(log.scans[i], keep_points=True) for i in keyframes]
    reference = dense_reference(log, odometry)
    validator = EdgeValidator(
        config.validation,
        scans,
        None if reference is None else reference[keyframes],
        # A worker process where the run may use more than one core (not a one-CPU Ray task).
        LocalMaps(log.scans, odometry, keyframes, ahead=fe.match_threads() > 1),
        network_threads=1,  # the cores are the loop threads' and the workers'
    )
    front = _front_end((scans, odometry[keyframes], validator), config, fe)
    try:
        edges = front.run(progress)
    finally:
        validator.close()
    return _Made(odometry, keyframes, (front, validator, edges), odometry_seconds)


def _chunks(stream: OdometryStream, log: ScanLog, progress: bool) -> Iterator[Chunk]:
    """The stream's chunks; where its worker dies, the rest of the odometry made here (the
    same: kiss-icp runs the scans from the first again)."""
    received = 0
    try:
        for chunk in stream.chunks():
            received = chunk.start + len(chunk.poses)
            yield chunk
    except RuntimeError:
        yield Chunk(received, scan_odometry(log.scans, progress=progress)[received:], {})


def _front_end_streamed(
    log: ScanLog,
    usable: NDArray[np.bool_],
    config: SlamConfig,
    fe: FrontEndConfig,
    on_pose: Callable[[int, NDArray[np.float64]], None] | None,
    progress: bool,
) -> _Made:
    """The odometry made in a worker, the front end taking its keyframes as they come."""
    t = time.perf_counter()
    total = len(log)
    odometry = np.full((total, 3), np.nan)
    keyframes: list[int] = []
    scans: list[Scan] = []
    # Room for every usable scan: the front end reads the rows of the keyframes it has.
    keyframe_odometry = np.full((int(usable.sum()), 3), np.nan)
    step = (fe.keyframe_distance, fe.keyframe_angle_deg)
    try:
        # Started before the model loads: the odometry needs none.
        stream = OdometryStream(log.scans, usable, step)
    except (OSError, RuntimeError):  # no processes here (no /dev/shm, a sandbox)
        return _front_end_after_odometry(log, usable, config, fe, on_pose, progress)
    local = LocalMaps(log.scans, odometry, keyframes)
    validator = EdgeValidator(config.validation, scans, None, local, network_threads=1)
    placing = validator.placing
    stream.place_with(placing)
    context = None if placing is None else placing[0]
    pick = KeyframePicker(fe.keyframe_distance, fe.keyframe_angle_deg)
    done = [0.0]

    def arrivals() -> Iterator[int]:
        """Keyframes ready, after each chunk (``odometry_stream.ready``)."""
        count = 0
        # Its own count: the front end's, beside it, cannot say how far the odometry is.
        bar = counter(total, "odometry", "scan", enabled=progress)
        for chunk in _chunks(stream, log, progress):
            end = chunk.start + len(chunk.poses)
            bar.update(len(chunk.poses))
            odometry[chunk.start : end] = chunk.poses
            for i in range(chunk.start, end):
                if on_pose is not None:
                    on_pose(i, odometry[i])
                if usable[i] and pick(odometry[i]):
                    keyframe_odometry[len(keyframes)] = odometry[i]
                    keyframes.append(i)
                    scans.append(dataclasses.replace(log.scans[i], keep_points=True))
            validator.adopt(chunk.placed)
            while count < len(keyframes) and ready(keyframes[count], end, total, context):
                count += 1
            yield count
        bar.close()
        done[0] = time.perf_counter() - t

    try:
        waiting = arrivals()
        first = next(count for count in waiting if count > 0)
        front = _front_end((scans, keyframe_odometry, validator), config, fe)
        edges = front.run(progress, itertools.chain([first], waiting))
    finally:
        validator.close()
    kept = np.asarray(keyframes, dtype=np.int64)
    return _Made(odometry, kept, (front, validator, edges), done[0])


def run_slam(log: ScanLog, config: SlamConfig, progress: bool = True) -> SlamResult:
    """Runs the whole pipeline on a log.

    Raises:
        InputError: The log has too few usable scans, or the validator cannot be set up.
    """
    seconds: dict[str, float] = {}
    usable = _usable(log)
    if usable.sum() < 2:
        raise InputError(
            log.path,
            f"has {int(usable.sum())} scan(s) with at least {MIN_POINTS} points; "
            "SLAM needs two or more",
        )
    check_loop_precision(config.validation)
    fe = config.front_end
    if config.validation.validator == "none":
        # ``none`` keeps every edge: no sequential match goes out for disagreeing with the
        # odometry either, so ``before`` and ``after`` stay one graph.
        fe = dataclasses.replace(fe, sequential_slide_check=False)
    stream = _between_stream(log, usable, fe)
    on_pose = stream.pose if stream is not None else None
    t = time.perf_counter()
    run = _front_end_streamed if _streams(log, config, fe) else _front_end_after_odometry
    made = run(log, usable, config, fe, on_pose, progress)
    odometry, keyframes, front, validator, edges = made.odometry, made.keyframes, *made.run
    seconds["odometry"] = made.odometry_seconds
    seconds["front_end"] = time.perf_counter() - t - made.odometry_seconds
    running = front.estimate.poses
    t = time.perf_counter()
    odo_kf = odometry[keyframes]
    # Every edge the matcher measured; a loop it could not place (no pose scored) has none.
    measured = [e for e in edges if e.kind == "sequential" or e.match.covariance is not None]
    # Each measured edge as the after graph would hold it, were it kept.
    as_kept = [kept_edge(e, odo_kf, config.graph, config.front_end) for e in measured]
    before = optimize(running, as_kept, config.graph)
    after_edges: list[GraphEdge] = []
    for e in edges:
        if e.kept:
            after_edges.append(kept_edge(e, odo_kf, config.graph, config.front_end))
        elif e.kind == "sequential":
            after_edges.append(fallback_edge(e, odo_kf, config.graph, config.front_end))
    after = optimize(running, after_edges, config.graph)
    seconds["back_end"] = time.perf_counter() - t
    t = time.perf_counter()
    if stream is not None:
        between = stream.result(odometry, keyframes, progress)
    else:
        between = place_between(log.scans, odometry, keyframes, progress)
    seconds["between"] = time.perf_counter() - t
    return SlamResult(
        keyframes=keyframes.astype(np.int64),
        odometry=odometry,
        edges=edges,
        running=running,
        before=before,
        after=after,
        threshold=validator.threshold,
        seconds=seconds,
        isam2_restarts=front.estimate.restarts,
        after_edges=after_edges,
        loop_bar=validator.loop_bar,
        between=between,
    )
