"""Where a corrected log's reference, not the map, is wrong: the SLAM table's relations checked
against the scans.

The ten corrected logs are scored against relations drawn from GMapping's own corrected poses,
and GMapping's map is torn in places (a revisit ~10° off in CSAIL's, ``reference_labels``). A
relation the run misses by more than ``--over`` metres is checked as the reference labels are
(``reference_labels.contradicts_reference``): the pairwise matcher starts at the reference, and
where it comes to rest at the run's pose, more of the scans agree there and the overlap fits far
better, the scans contradict the reference. Where it rests at the reference, they confirm it and
the run's error is real; elsewhere, they decide nothing (little overlap, or a corridor).

Each row runs ``vgm-studio slam`` as ``bench_slam.py`` does (bundled validator, ``--robust
none``), with ``--trajectory`` for every scan's pose; its mean error is the table's.

Run: python benchmarks/reference_check.py [--logs freiburg-campus,acapulco] [--over 0.1]
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
from _common import REPO, machine, table
from bench_slam import CORRECTED, arguments

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.graph.metrics import reference_relations
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.reference_labels import LabelThresholds, contradicts_reference

OUT = REPO / "build" / "reference_check"
# The matcher's rest "at" a pose: within the reference labels' success tolerance.
AT = LabelThresholds().success_xy


def trajectory(path: Path) -> np.ndarray:
    """(x, y, θ) of every scan from a TUM file (``slam --trajectory``)."""
    rows = np.loadtxt(path, ndmin=2)
    return np.column_stack([rows[:, 1], rows[:, 2], 2.0 * np.arctan2(rows[:, 6], rows[:, 7])])


def verdict(log, relation, estimate: np.ndarray, matcher: ScanMatcher) -> str:
    a, b = log.scans[relation.a], log.scans[relation.b]
    rest = matcher.match(a, b, relation.pose).estimate
    judged = [matcher.judge(a, b, pose) for pose in (relation.pose, rest)]
    at_ref, at_rest = ((0.0, 0.0) if f is None else (f.inlier_ratio, f.fit) for f in judged)
    if contradicts_reference(estimate, rest, at_ref, at_rest):
        return "contradict the reference"
    if se2.pose_error(relation.pose, rest)[0] <= AT:
        return "confirm the reference"
    return "decide nothing"


def check(name: str, over: float) -> list[list[str]]:
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"{name}.txt"
    args = arguments(name, OUT / f"{name}.json", pictures=False)
    cmd = [sys.executable, "-m", "vgm_studio.tools.cmd", "slam", *args, "--trajectory", path]
    subprocess.run([str(c) for c in cmd], check=True, capture_output=True, text=True)
    log = open_log(args[0])
    poses = trajectory(path)
    relations = reference_relations([s.reference for s in log.scans])
    matcher = ScanMatcher()
    errors, kinds = [], []
    for r in relations:
        estimate = se2.between(poses[r.a], poses[r.b])
        error = se2.pose_error(r.pose, estimate)[0]
        errors.append(error)
        kinds.append(verdict(log, r, estimate, matcher) if error > over else f"≤ {over} m")
    err, kind = np.array(errors), np.array(kinds)
    rows = []
    for k in (f"≤ {over} m", "confirm the reference", "decide nothing", "contradict the reference"):
        mine = kind == k
        rows.append([name, k, str(int(mine.sum())), f"{err[mine].sum() / len(err):.4f}"])
    kept = kind != "contradict the reference"
    rows.append([name, "all", str(len(err)), f"{err.mean():.4f}"])
    rows.append([name, "all but contradicted", str(int(kept.sum())), f"{err[kept].mean():.4f}"])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="freiburg-campus,acapulco", help="Corrected logs.")
    parser.add_argument("--over", type=float, default=0.1, help="Check relations off by more.")
    args = parser.parse_args()
    names = [n for n in args.logs.split(",") if n]
    unknown = [n for n in names if n not in CORRECTED]
    if unknown:
        sys.exit(f"error: not a corrected log of the table: {', '.join(unknown)}")
    if not (math.isfinite(args.over) and args.over > 0):
        sys.exit(f"error: --over must be a positive number of metres, not {args.over}")
    rows = [r for n in names for r in check(n, args.over)]
    print(f"# {machine()}")
    head = ["log", f"relations off by more than {args.over} m: the scans…", "relations",
            "share of the mean error, m"]  # fmt: skip
    print(table(head, rows))


if __name__ == "__main__":
    main()
