"""Two runs of one log compared: relation errors against the run-to-run noise, loops by scan
pair, keyframes that moved.

Everything here is arithmetic on the two ``--json`` documents; on two full Intel runs it
takes well under a second. The maps are drawn apart (``compare/overlay.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vgm_studio.compare.loops import LoopChanges, changes, match_loops
from vgm_studio.compare.runs import TRAJECTORIES, Run


@dataclass(frozen=True)
class Noise:
    """How far two runs of the same code on the same log may differ by chance.

    A change within ``floor + share × base`` is called noise. The defaults come from the
    nudged spread BENCHMARKS.md measures (``benchmarks/bench_slam.py --nudge 1,2,3``, the
    odometry nudged by 1e-9, another machine's rounding): seven buildings spread by 1 mm or
    less, the fickle ones (CSAIL 0.055–0.076 m, the infinite corridor 0.057–0.075 m) by up to
    a third of their error. The floor covers the first, the share a tenth of the second; a
    log known to be fickle deserves a larger share.

    Attributes:
        floor_m: Absolute part of the translation noise, metres.
        share: Relative part, a fraction of the base run's error (both units).
        floor_deg: Absolute part of the rotation noise, degrees.
    """

    floor_m: float = 0.002
    share: float = 0.10
    floor_deg: float = 0.05

    def of(self, base: float, floor: float) -> float:
        """The noise around a base value with this floor."""
        return floor + self.share * abs(base)


@dataclass(frozen=True)
class ErrorChange:
    """One trajectory's relation error in both runs.

    Attributes:
        trajectory: ``odometry``/``input``, ``before`` or ``after``.
        unit: ``m`` (translation) or ``°`` (rotation).
        base: The base run's mean error.
        new: The new run's.
        noise: The change the noise model allows.
    """

    trajectory: str
    unit: str
    base: float
    new: float
    noise: float

    @property
    def delta(self) -> float:
        return self.new - self.base

    @property
    def relative(self) -> float:
        """The change as a share of the base (inf from a base of 0)."""
        if self.base == 0:
            return 0.0 if self.delta == 0 else math.inf
        return self.delta / self.base

    @property
    def verdict(self) -> str:
        """``worse``, ``better`` or ``within noise``."""
        if abs(self.delta) <= self.noise:
            return "within noise"
        return "worse" if self.delta > 0 else "better"


@dataclass(frozen=True)
class MovedKeyframe:
    """A keyframe both runs made (the same scan) whose after pose moved between them."""

    scan: int
    metres: float
    degrees: float


@dataclass(frozen=True)
class CompareConfig:
    """How two runs are compared.

    Attributes:
        noise: The run-to-run noise of the relation errors.
        scan_tolerance: Loops whose ends differ by at most this many scans are the same loop
            (keyframes 0.5 m apart on Intel lie ~9 scans apart; an audit's vertex ids must
            agree exactly).
        moved_m: A keyframe moved when its after pose differs by more than this…
        moved_deg: …or turned by more than this.
    """

    noise: Noise = field(default_factory=Noise)
    scan_tolerance: int = 5
    moved_m: float = 0.10
    moved_deg: float = 2.0


@dataclass
class Comparison:
    """What changed from the base run to the new one.

    Attributes:
        base: The base run.
        new: The new run.
        config: How they were compared.
        errors: Relation errors of the trajectories both runs scored, translation then rotation.
        loops: The loop changes.
        common_keyframes: Keyframes at scans both runs made keyframes of (slam only).
        moved: Those that moved more than the threshold, the largest first.
    """

    base: Run
    new: Run
    config: CompareConfig
    errors: list[ErrorChange]
    loops: LoopChanges
    common_keyframes: int = 0
    moved: list[MovedKeyframe] = field(default_factory=list)

    def error(self, trajectory: str, unit: str) -> ErrorChange | None:
        """The change of one trajectory's error, None where either run has none."""
        for e in self.errors:
            if e.trajectory == trajectory and e.unit == unit:
                return e
        return None

    @property
    def unchanged(self) -> bool:
        """No error beyond noise, no loop decided otherwise, no keyframe moved."""
        loops = self.loops
        return (
            all(e.verdict == "within noise" for e in self.errors)
            and not (loops.newly_kept or loops.newly_dropped or loops.flipped)
            and not self.moved
        )


def compare_runs(base: Run, new: Run, config: CompareConfig | None = None) -> Comparison:
    """Compares two runs of one log (``runs.same_subject`` checks that first)."""
    config = config or CompareConfig()
    tolerance = config.scan_tolerance if base.kind == "slam" else 0
    loops = changes(match_loops(base.loops, new.loops, tolerance))
    common, moved = _moved(base, new, config)
    return Comparison(
        base, new, config, _error_changes(base, new, config.noise), loops, common, moved
    )


def _error_changes(base: Run, new: Run, noise: Noise) -> list[ErrorChange]:
    out = []
    for name in TRAJECTORIES:
        b, n = base.errors.get(name), new.errors.get(name)
        if b is None or n is None:
            continue
        out.append(
            ErrorChange(
                name, "m", b.trans_mean, n.trans_mean, noise.of(b.trans_mean, noise.floor_m)
            )
        )
        out.append(
            ErrorChange(
                name, "°", b.rot_mean_deg, n.rot_mean_deg, noise.of(b.rot_mean_deg, noise.floor_deg)
            )
        )
    return out


def _moved(base: Run, new: Run, config: CompareConfig) -> tuple[int, list[MovedKeyframe]]:
    """Keyframes at the same scan in both runs whose after poses differ.

    Both after graphs are anchored at the first keyframe's odometry pose, so their frames
    agree and the poses compare as they are.
    """
    if base.keyframe_scans is None or new.keyframe_scans is None:
        return 0, []
    assert base.after_poses is not None and new.after_poses is not None
    scans, bi, ni = np.intersect1d(base.keyframe_scans, new.keyframe_scans, return_indices=True)
    pb, pn = base.after_poses[bi], new.after_poses[ni]
    metres = np.hypot(*(pn[:, :2] - pb[:, :2]).T)
    turned = np.degrees(np.abs((pn[:, 2] - pb[:, 2] + np.pi) % (2 * np.pi) - np.pi))
    far = np.flatnonzero((metres > config.moved_m) | (turned > config.moved_deg))
    order = far[np.argsort(-metres[far], kind="stable")]
    moved = [MovedKeyframe(int(scans[i]), float(metres[i]), float(turned[i])) for i in order]
    return len(scans), moved
