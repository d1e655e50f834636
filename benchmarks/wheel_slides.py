"""Where kiss-icp moves the wheels' step far, who is right: the wheels or ICP?

For each GMapping-corrected log with wheel odometry, kiss-icp runs predicted by the wheels'
steps with no limit on how far it may move them (``scan_odometry(max_slide=inf)``, the
odometry before ac146b7). Each step ICP moved by more than a threshold is scored against the
step between the log's corrected poses: the wheels' step or ICP's, whichever is nearer in
translation. This is why ``scan_odometry`` keeps the wheels' translation (``max_slide`` 0).

Run: python benchmarks/wheel_slides.py [--logs acapulco,csail]
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
from _common import datasets_dir, machine, table
from bench_slam import CORRECTED

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.slam.odometry import has_wheels, scan_odometry
from vgm_studio.slam.scoring import with_own_reference

THRESHOLDS = (0.1, 0.2, 0.3)


def _steps(poses: np.ndarray) -> np.ndarray:
    return se2.between(poses[:-1], poses[1:])


def _apart(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """How far each step of ``q`` ends from the same step of ``p``, metres."""
    d = se2.between(p, q)
    return np.hypot(d[:, 0], d[:, 1])


def slides(name: str) -> list[str] | None:
    """One row: per threshold, the steps ICP moved further and who was nearer the truth."""
    path = datasets_dir() / "radish-corrected" / f"{name}-corrected.log"
    scans = with_own_reference(open_log(path)).scans
    if not has_wheels(scans):
        return None
    icp = _steps(scan_odometry(scans, progress=False, max_slide=math.inf))
    wheels = _steps(np.array([s.odometry for s in scans]))
    truth = _steps(np.array([s.reference for s in scans]))
    moved = _apart(wheels, icp)
    off_wheels, off_icp = _apart(truth, wheels), _apart(truth, icp)
    row = [name, str(len(scans))]
    for limit in THRESHOLDS:
        far = moved > limit
        row.append(f"{int(far.sum())}: {int((off_wheels[far] < off_icp[far]).sum())} / "
                   f"{int((off_icp[far] < off_wheels[far]).sum())}")  # fmt: skip
    row.append(f"{moved.max():.2f}")
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default=",".join(CORRECTED), help="Corrected logs.")
    names = [n for n in parser.parse_args().logs.split(",") if n]
    unknown = [n for n in names if n not in CORRECTED]
    if unknown:
        sys.exit(f"error: not a corrected log of the table: {', '.join(unknown)}")
    rows = [r for n in names if (r := slides(n)) is not None]
    print(f"# {machine()}")
    head = ["log", "scans"]
    head += [f"ICP moved > {t} m: steps: wheels / ICP nearer" for t in THRESHOLDS]
    head.append("most moved, m")
    total = ["all", str(sum(int(r[1]) for r in rows))]
    for k in range(len(THRESHOLDS)):
        cells = [r[2 + k].replace(":", " /").split(" / ") for r in rows]
        sums = [sum(int(c[j]) for c in cells) for j in range(3)]
        total.append(f"{sums[0]}: {sums[1]} / {sums[2]}")
    total.append(max(r[-1] for r in rows))
    print(table(head, [*rows, total]))


if __name__ == "__main__":
    main()
