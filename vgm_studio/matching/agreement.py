"""Do the scans and the odometry tell the same story? A check on matched sequential edges.

Between two consecutive keyframes the matcher measures the robot's motion from the scans and
the wheels measure it too. They differ by the matcher's error and the odometry's; a laser
whose mount is wrong (off-centre, turned, upside down), the wrong odometry topic, or wheels
that slip make them differ by far more, and the same way every time. The check asks two
things of the edges, each judged against the noise the edges themselves declare:

* translation: each edge's disagreement over its standard deviation, that is the matcher's own
  covariance plus the odometry's allowance (``ODOMETRY_FRACTION`` of the step), and the median
  of those ratios. For agreeing sources the ratio is Rayleigh-distributed with median 1.18;
  a median above ``MAX_MEDIAN_RATIO`` is not chance.
* heading: among the turns both can resolve (odometry's turn beyond ``TURN_SIGMAS`` standard
  deviations), how many the scans see turning the other way. A mirrored scan (a laser upside
  down) turns every one of them the wrong way; chance turns none.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import ScanLog, mount_line
from vgm_studio.matching.edges import Edge
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.matcher import ScanMatcher

# Wheel odometry of a working robot is good to a few per cent of the distance and angle
# travelled; 5% is the allowance before a disagreement counts against the sources.
ODOMETRY_FRACTION = 0.05
# Median of |disagreement| / σ beyond which the sources disagree (agreeing ones give ~1.2).
MAX_MEDIAN_RATIO = 3.0
# A turn counts when odometry's heading change is this many σ from zero.
TURN_SIGMAS = 3.0
# Fewer comparable edges than this say nothing systematic.
MIN_EDGES = 5
# Matched steps the check of ``info --check`` makes at most, spread over the log.
CHECK_PAIRS = 200


@dataclass(frozen=True)
class Motion:
    """One matched step: scan b in scan a's frame, and the matcher's covariance (or None)."""

    a: int
    b: int
    estimate: NDArray[np.float64]
    covariance: NDArray[np.float64] | None


@dataclass(frozen=True)
class Agreement:
    """What the check found.

    Attributes:
        edges: Steps compared (both scans with odometry).
        median_disagreement: Median translation disagreement, metres.
        median_spread: Median σ of the translation disagreement (matcher + odometry), metres.
        median_ratio: Median of the per-step disagreement / σ.
        turns: Steps whose turn odometry resolves.
        opposite_turns: Of those, steps the scans see turning the other way.
    """

    edges: int
    median_disagreement: float
    median_spread: float
    median_ratio: float
    turns: int
    opposite_turns: int

    @property
    def translation_disagrees(self) -> bool:
        return self.edges >= MIN_EDGES and self.median_ratio > MAX_MEDIAN_RATIO

    @property
    def heading_disagrees(self) -> bool:
        return self.turns >= MIN_EDGES and self.opposite_turns > self.turns / 2

    @property
    def disagrees(self) -> bool:
        return self.translation_disagrees or self.heading_disagrees

    def figures(self) -> str:
        return (
            f"median {100 * self.median_disagreement:.1f} cm between {self.edges} sequential "
            f"matches and odometry, {self.median_ratio:.1f}× their spread "
            f"({100 * self.median_spread:.2f} cm); heading increments of opposite sign in "
            f"{self.opposite_turns} of {self.turns} turns"
        )

    def warning(self, mount_source: str | None = None) -> str:
        """One line: what disagrees, by how much, and the likely causes."""
        mount = f"; the mount now: {mount_source}" if mount_source else ""
        return (
            f"warning: the scans and odometry disagree ({self.figures()}). Likely causes: the "
            "laser's mount (give --laser-pose X,Y,YAW, and --laser-flipped if it is upside "
            f"down{mount}), the wrong odometry topic (--odom-topic), or wheel slip"
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "edges": self.edges,
            "median_disagreement_m": self.median_disagreement,
            "median_spread_m": self.median_spread,
            "median_ratio": self.median_ratio,
            "turns": self.turns,
            "opposite_turns": self.opposite_turns,
            "disagrees": self.disagrees,
        }


def _sigmas(motion: Motion, odo: NDArray[np.float64]) -> tuple[float, float]:
    """σ of the translation and heading disagreement of one step."""
    cov = motion.covariance
    # A covariance is never negative; one that says so (a foreign one) counts as none.
    match_t2 = 0.0 if cov is None else max(0.0, float(cov[0, 0] + cov[1, 1]))
    match_r2 = 0.0 if cov is None else max(0.0, float(cov[2, 2]))
    odo_t2 = (ODOMETRY_FRACTION * math.hypot(odo[0], odo[1])) ** 2
    odo_r2 = (ODOMETRY_FRACTION * abs(odo[2])) ** 2
    return math.sqrt(match_t2 + odo_t2), math.sqrt(match_r2 + odo_r2)


def check_agreement(log: ScanLog, motions: Iterable[Motion]) -> Agreement | None:
    """Compares matched steps with the log's odometry; None when no step has odometry."""
    dist, spread, ratio = [], [], []
    turns = opposite = 0
    for m in motions:
        oa, ob = log.scans[m.a].odometry, log.scans[m.b].odometry
        if oa is None or ob is None or not np.all(np.isfinite(m.estimate)):
            continue
        odo = se2.between(oa, ob)
        sigma_t, sigma_r = _sigmas(m, odo)
        d = math.hypot(m.estimate[0] - odo[0], m.estimate[1] - odo[1])
        dist.append(d)
        spread.append(sigma_t)
        ratio.append(d / sigma_t if sigma_t > 0 else (0.0 if d == 0 else math.inf))
        if abs(odo[2]) > TURN_SIGMAS * sigma_r and sigma_r > 0:
            turns += 1
            opposite += bool(np.sign(m.estimate[2]) == -np.sign(odo[2]))
    if not dist:
        return None
    return Agreement(
        edges=len(dist),
        median_disagreement=float(np.median(dist)),
        median_spread=float(np.median(spread)),
        median_ratio=float(np.median(ratio)),
        turns=turns,
        opposite_turns=opposite,
    )


def motions_of(
    pairs: Sequence[tuple[int, int]],
    estimates: Sequence[Any],
    covariances: Sequence[Any],
) -> list[Motion]:
    """Motions from parallel lists (edges' scan indices, estimates, covariances or None)."""
    return [
        Motion(a, b, np.asarray(e, dtype=np.float64), None if c is None else np.asarray(c))
        for (a, b), e, c in zip(pairs, estimates, covariances, strict=True)
    ]


def edges_agreement(log: ScanLog, edges: Sequence[Edge]) -> Agreement | None:
    """The check on a log's sequential candidate edges."""
    seq = [e for e in edges if e.kind == "sequential"]
    return check_agreement(
        log,
        motions_of(
            [(e.a, e.b) for e in seq],
            [e.estimate for e in seq],
            [e.match.get("covariance") for e in seq],
        ),
    )


def disagreement_warning(log: ScanLog, agreement: Agreement | None) -> str | None:
    """The one warning line when the scans and the odometry disagree, else None.

    None too when only some scans have odometry: the runs then go without it (``slam``'s
    odometry steers only where every scan has some), so a disagreement would blame the
    laser's mount for readings nothing used.
    """
    if agreement is None or not agreement.disagrees or not log.has_odometry:
        return None
    return agreement.warning(mount_line(log))


def check_log(
    log: ScanLog,
    matcher: ScanMatcher | None = None,
    keyframe_distance: float = 0.25,
    keyframe_angle_deg: float = 10.0,
) -> Agreement | None:
    """Matches up to ``CHECK_PAIRS`` consecutive keyframes from odometry and checks them.

    Returns None when the log has no odometry on two or more scans.
    """
    has = np.flatnonzero([s.odometry is not None for s in log.scans])
    if len(has) < 2:
        return None
    odometry = np.array([log.scans[i].odometry for i in has], dtype=np.float64)
    keys = has[select_keyframes(odometry, keyframe_distance, keyframe_angle_deg)]
    steps = list(itertools.pairwise(keys))
    if len(steps) > CHECK_PAIRS:
        steps = [steps[i] for i in np.linspace(0, len(steps) - 1, CHECK_PAIRS).astype(int)]
    matcher = matcher or ScanMatcher()
    motions = []
    for a, b in steps:
        sa, sb = log.scans[a], log.scans[b]
        assert sa.odometry is not None and sb.odometry is not None
        result = matcher.match(sa, sb, se2.between(sa.odometry, sb.odometry))
        motions.append(Motion(int(a), int(b), result.estimate, result.covariance))
        matcher.forget(sa)
    return check_agreement(log, motions)
