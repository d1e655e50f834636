"""Where a SLAM run's sequential steps are furthest from the reference, and whether the
matcher's score would have preferred the reference step there.

Run: python benchmarks/step_scores.py [LOG] [--worst 10]

LOG is a log with reference poses (default: the GMapping-corrected Örebro log, whose scans are
1–4 m apart with no wheel odometry). The whole run is made with the bundled ``vgmnet``, then
for the ``--worst`` keyframe steps (by the `after` graph's translation error against the
reference) each step is scored on the previous keyframe's scan alone:

- ``score``: the correlative score (mean likelihood of the scan's points on the previous scan's
  grid, 0..1) at the kept or fallback step, and at the reference step moved to the best pose
  within 0.6 m and 8° of it (the reference is GMapping's, good to a few centimetres);
- ``hit / free``: the scan's points that land within 0.15 m of a reading of the previous scan
  along its beam, and those that land in space the previous scan saw through.

A step whose reference scores lower than the matched step is one no wider search can mend:
the score itself prefers the wrong step (in a corridor, a short step keeps more of the scan
inside what the previous scan saw). The free-space count says whether a score that also
reads free space would.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from _common import datasets_dir, machine, table
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.scans import Scan
from vgm_studio.datasets.source import JoinOptions, read_slam_source
from vgm_studio.matching.branch_bound import SearchWindow, branch_and_bound
from vgm_studio.matching.submap import Submap
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.slam.config import SlamConfig, ValidationConfig
from vgm_studio.slam.pipeline import dense_reference, run_slam
from vgm_studio.slam.scoring import with_own_reference

NEAR_REFERENCE = SearchWindow(0.6, math.radians(8.0))
AT_POSE = SearchWindow(0.0, 0.0)
HIT_TOLERANCE = 0.15


def visibility(
    previous: Scan, points: NDArray[np.float64], pose: NDArray[np.float64]
) -> tuple[int, int]:
    """Points (in their own frame, placed at ``pose`` in the previous scan's frame) that hit a
    reading of the previous scan, and those in space it saw through."""
    p = se2.transform_points(pose, points)
    r = np.hypot(p[:, 0], p[:, 1])
    beam = np.round((np.arctan2(p[:, 1], p[:, 0]) - previous.angle_min) / previous.angle_increment)
    seen = (beam >= 0) & (beam < previous.num_beams)
    reading = np.full(len(p), np.inf)
    reading[seen] = previous.ranges[beam[seen].astype(np.intp)]
    hit = seen & (reading < previous.max_range) & (np.abs(r - reading) < HIT_TOLERANCE)
    free = seen & (r < reading - HIT_TOLERANCE)
    return int(hit.sum()), int(free.sum())


def main() -> None:
    default = datasets_dir() / "radish-corrected" / "orebro-corrected.log"
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("log", nargs="?", type=Path, default=default)
    parser.add_argument("--worst", type=int, default=10, help="Steps to show (default 10).")
    args = parser.parse_args()
    source = read_slam_source(args.log, ReadOptions(), None, None, JoinOptions(0.05, 0.0))
    log = with_own_reference(source.log)
    config = SlamConfig(validation=ValidationConfig(validator="vgmnet", model=BUNDLED_MODEL))
    result = run_slam(log, config)
    reference = dense_reference(log, result.odometry)
    if reference is None:
        raise SystemExit(f"{args.log}: has no reference poses to compare the steps with")
    ref = reference[result.keyframes]
    after = result.after.poses
    scans = [log.scans[i] for i in result.keyframes]
    steps = {e.b: e for e in result.edges if e.kind == "sequential"}
    errors = []
    for k in range(1, len(after)):
        off = se2.between(se2.between(after[k - 1], after[k]), se2.between(ref[k - 1], ref[k]))
        errors.append((math.hypot(off[0], off[1]), k))
    rows, prefer_match = [], 0
    for _, k in sorted(errors, reverse=True)[: args.worst]:
        edge, previous, points = steps[k], scans[k - 1], scans[k].points()
        grid = Submap.from_points(previous.points())
        held = edge.estimate if edge.kept else edge.guess
        truth = se2.between(ref[k - 1], ref[k])
        near = branch_and_bound(grid, points, truth, NEAR_REFERENCE)
        at = branch_and_bound(grid, points, held, AT_POSE)
        if near is None or at is None:
            continue
        prefer_match += at.score > near.score
        off = se2.between(held, truth)
        rows.append(
            [
                str(k),
                f"{math.hypot(truth[0], truth[1]):.2f}",
                f"{math.hypot(off[0], off[1]):.2f} m, {math.degrees(abs(off[2])):.1f}°",
                f"{edge.p_success:.2f} ({'kept' if edge.kept else 'odometry'})",
                f"{at.score:.3f} / {near.score:.3f}",
                "{} / {}".format(*visibility(previous, points, held)),
                "{} / {}".format(*visibility(previous, points, near.pose)),
            ]
        )
    print(f"# {args.log.name}: the {len(rows)} keyframe steps furthest from the reference")
    print(f"# {machine()}")
    header = ["keyframe", "reference step m", "held step off by", "p (held)", "score held / ref"]
    print(table([*header, "hit / free held", "hit / free ref"], rows))
    shown = len(rows)
    print(f"the score prefers the held step to the reference at {prefer_match} of {shown}")


if __name__ == "__main__":
    main()
