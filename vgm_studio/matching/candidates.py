"""Candidate edges: which scan pairs to match, from which guess, and their reference labels.

Sequential edges join consecutive keyframes, guessed from odometry. Loop edges join scans far
apart in the sequence but near in space; with reference poses (the benchmark protocol) the guess
is the reference relative pose perturbed by Gaussian noise, otherwise it is odometry's.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from vgm_studio.core import se2
from vgm_studio.datasets.relations import MatchedRelation
from vgm_studio.datasets.scans import Scan, ScanLog
from vgm_studio.matching.edges import Edge, EdgeKind, Label, edge_id
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.odometry import lidar_odometry
from vgm_studio.matching.reference_labels import (
    LabelThresholds,
    contradicts_reference,
    reference_label,
)
from vgm_studio.progress import track


@dataclass(frozen=True)
class CandidateConfig:
    """Which pairs become candidate edges.

    Attributes:
        sequential: Make sequential edges between consecutive keyframes.
        loops: Make loop edges.
        keyframe_distance: A new keyframe after this much travel, metres (0: every scan).
        keyframe_angle_deg: …or after this much rotation, degrees.
        min_gap: Loop pairs are at least this many scans apart.
        max_distance: Loop pairs' poses are within this distance, metres.
        max_angle_deg: …and within this heading difference, degrees.
        max_loops: Loop pairs kept at most (sampled with ``seed``).
        seed: Seed for sampling pairs and drawing guess noise.
        noise_xy: σ of the Gaussian noise added to x and y of reference guesses, metres.
        noise_theta_deg: σ of the noise added to θ of reference guesses, degrees.
    """

    sequential: bool = True
    loops: bool = True
    keyframe_distance: float = 0.0
    keyframe_angle_deg: float = 0.0
    min_gap: int = 50
    max_distance: float = 3.0
    max_angle_deg: float = 45.0
    max_loops: int = 2000
    seed: int = 0
    noise_xy: float = 0.3
    noise_theta_deg: float = 5.0


@dataclass(frozen=True)
class _Pair:
    a: int
    b: int
    kind: EdgeKind
    guess: NDArray[np.float64]
    reference: NDArray[np.float64] | None


def loop_pairs(
    poses: NDArray[np.float64], config: CandidateConfig, usable: NDArray[np.bool_] | None = None
) -> NDArray[np.int64]:
    """All (a, b), a < b, at least ``min_gap`` apart, within ``max_distance`` and ``max_angle``,
    sampled down to ``max_loops`` with ``seed``. Returns (K, 2) sorted by (a, b)."""
    idx = np.arange(len(poses)) if usable is None else np.flatnonzero(usable)
    if len(idx) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = cKDTree(poses[idx, :2]).query_pairs(config.max_distance, output_type="ndarray")
    pairs = np.sort(idx[pairs], axis=1)
    a, b = pairs[:, 0], pairs[:, 1]
    dtheta = np.abs(se2.wrap_angle(poses[b, 2] - poses[a, 2]))
    pairs = pairs[(b - a >= config.min_gap) & (dtheta <= math.radians(config.max_angle_deg))]
    pairs = pairs[_sample(len(pairs), config)]
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    ordered: NDArray[np.int64] = pairs[order]
    return ordered


def _sample(count: int, config: CandidateConfig) -> NDArray[np.int64]:
    """Sorted indices of at most ``max_loops`` of ``count`` items, drawn with ``seed``."""
    if count <= config.max_loops:
        return np.arange(count)
    rng = np.random.default_rng(config.seed)
    return np.sort(rng.choice(count, size=config.max_loops, replace=False))


def _noise(config: CandidateConfig, count: int) -> NDArray[np.float64]:
    # A stream of its own, so the noise of an edge does not depend on how pairs were sampled.
    rng = np.random.default_rng([config.seed, 1])
    sd = np.array([config.noise_xy, config.noise_xy, math.radians(config.noise_theta_deg)])
    noise: NDArray[np.float64] = rng.normal(size=(count, 3)) * sd
    return noise


def plan_pairs(
    log: ScanLog,
    config: CandidateConfig,
    relations: list[MatchedRelation] | None = None,
    progress: bool = True,
) -> tuple[list[_Pair], dict[str, Any]]:
    """Chooses the pairs to match and their guesses. Returns them and notes for ``params``."""
    notes: dict[str, Any] = {}
    odometry = log.odometry_poses()
    if odometry is None:
        odometry = lidar_odometry(log.scans, progress=progress)
        notes["odometry"] = "kiss-icp"
    else:
        notes["odometry"] = "log"
    refs = [s.reference for s in log.scans]
    has_ref = np.array([r is not None for r in refs])
    pairs: list[_Pair] = []
    if config.sequential:
        pool = np.arange(len(refs))
        if 2 <= has_ref.sum() < len(refs):
            # A reference that covers only some scans (GMapping keeps one scan in ~15) makes
            # those scans the keyframes; otherwise nearly every sequential edge would join a
            # scan without a reference and come out unlabelled.
            pool = np.flatnonzero(has_ref)
            notes["keyframes_from"] = "scans with a reference pose"
        keys = pool[
            select_keyframes(odometry[pool], config.keyframe_distance, config.keyframe_angle_deg)
        ]
        notes["keyframes"] = len(keys)
        for a, b in itertools.pairwise(keys):
            ra, rb = refs[a], refs[b]
            ref = None if ra is None or rb is None else se2.between(ra, rb)
            pairs.append(
                _Pair(int(a), int(b), "sequential", se2.between(odometry[a], odometry[b]), ref)
            )
    if config.loops and relations is not None:
        notes["loop_source"] = "relations"
        chosen = [relations[i] for i in _sample(len(relations), config)]
        noise = _noise(config, len(chosen))
        for rel, n in zip(chosen, noise, strict=True):
            pairs.append(_Pair(rel.a, rel.b, "loop", _perturb(rel.pose, n), rel.pose))
    elif config.loops:
        if has_ref.sum() >= 2:
            notes["loop_source"] = "reference"
            poses = np.array([r if r is not None else np.zeros(3) for r in refs])
            found = loop_pairs(poses, config, has_ref)
            noise = _noise(config, len(found))
            for (a, b), n in zip(found, noise, strict=True):
                ref = se2.between(poses[a], poses[b])
                pairs.append(_Pair(int(a), int(b), "loop", _perturb(ref, n), ref))
        else:
            notes["loop_source"] = "odometry"
            for a, b in loop_pairs(odometry, config):
                pairs.append(
                    _Pair(int(a), int(b), "loop", se2.between(odometry[a], odometry[b]), None)
                )
    return pairs, notes


def _perturb(pose: NDArray[np.float64], noise: NDArray[np.float64]) -> NDArray[np.float64]:
    out = pose + noise
    out[2] = float(se2.wrap_angle(out[2]))
    return out


def make_candidates(
    log: ScanLog,
    matcher: ScanMatcher,
    config: CandidateConfig | None = None,
    thresholds: LabelThresholds | None = None,
    relations: list[MatchedRelation] | None = None,
    params: dict[str, Any] | None = None,
    progress: bool = True,
) -> list[Edge]:
    """Plans, matches and labels the candidate edges of a log.

    Args:
        log: The log, with reference poses on its scans where known.
        matcher: The scan matcher.
        config: Which pairs to make.
        thresholds: Reference label thresholds.
        relations: Relations tied to scans; when given they are the loop pairs and references.
        params: Extra settings to record in every edge (read options, reference source).
        progress: Show progress bars.

    Returns:
        The edges in order: sequential first, then loops, each sorted by (a, b).
    """
    config = config or CandidateConfig()
    thresholds = thresholds or LabelThresholds()
    pairs, notes = plan_pairs(log, config, relations, progress)
    mount = log.mount
    recorded = {
        **(params or {}),
        "mount": None if mount is None else {**mount.to_json(), "source": log.mount_source},
        "candidates": asdict(config),
        "labels": asdict(thresholds),
        "matcher": asdict(matcher.config),
        **notes,
    }
    # Absolute, so the edges file still finds its log when read from another folder.
    log_path = str(Path(log.path).resolve())
    return [
        _matched(log, log_path, p, matcher, thresholds, recorded)
        for p in track(pairs, "matching", "edge", enabled=progress)
    ]


def _matched(
    log: ScanLog,
    log_path: str,
    pair: _Pair,
    matcher: ScanMatcher,
    thresholds: LabelThresholds,
    recorded: dict[str, Any],
) -> Edge:
    """One planned pair matched, and labelled against its reference when it has one."""
    p = pair
    a, b = log.scans[p.a], log.scans[p.b]
    result = matcher.match(a, b, p.guess)
    estimate = [float(v) for v in result.estimate]
    figures = result.figures()
    label: Literal["success", "failure", "ambiguous"] | None = None
    if p.reference is not None:
        label, check = checked_label(a, b, p.reference, result.estimate, matcher, thresholds)
        if check is not None:
            figures["reference_check"] = check
    return Edge(
        # A scan pair matched under another laser mount is another edge.
        edge_id=edge_id(
            log.content_hash, p.a, p.b, estimate, "" if log.mount is None else log.mount.id_text()
        ),
        log_path=log_path,
        log_sha256=log.content_hash,
        a=p.a,
        b=p.b,
        timestamp_a=log.scans[p.a].timestamp,
        timestamp_b=log.scans[p.b].timestamp,
        kind=p.kind,
        guess=[float(v) for v in p.guess],
        estimate=estimate,
        match=figures,
        reference=None if p.reference is None else [float(v) for v in p.reference],
        label=label,
        params=recorded,
    )


def checked_label(
    a: Scan,
    b: Scan,
    reference: NDArray[np.float64],
    estimate: NDArray[np.float64],
    matcher: ScanMatcher,
    thresholds: LabelThresholds,
) -> tuple[Label, dict[str, Any] | None]:
    """The reference label of a matched pair, and where a failure was checked against the
    scans (``thresholds.check_reference``) the check's JSON-ready figures: the matcher
    started at the reference, and whether the scans contradict the reference
    (``reference_labels.contradicts_reference``). A failure they contradict is ``ambiguous``."""
    label = reference_label(reference, estimate, thresholds)
    if label != "failure" or not thresholds.check_reference:
        return label, None
    reference = np.asarray(reference, dtype=np.float64)
    rest = matcher.match(a, b, reference).estimate
    figures = [matcher.judge(a, b, pose) for pose in (reference, rest)]
    at_reference, at_rest = ((0.0, 0.0) if f is None else (f.inlier_ratio, f.fit) for f in figures)
    contradicted = contradicts_reference(estimate, rest, at_reference, at_rest, thresholds)
    check = {
        "from_reference": [float(v) for v in rest],
        "inlier_ratio_at_reference": at_reference[0],
        "inlier_ratio_from_reference": at_rest[0],
        "fit_at_reference": at_reference[1],
        "fit_from_reference": at_rest[1],
        "contradicted": contradicted,
    }
    return ("ambiguous" if contradicted else label), check
