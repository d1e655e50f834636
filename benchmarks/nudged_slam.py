"""``vgm-studio`` with the SLAM run's kiss-icp odometry nudged by rounding-level noise.

Run: python benchmarks/nudged_slam.py SEED slam LOG [options]

Every pose of the odometry gets Gaussian noise of σ 1e-9 (metres and radians), seeded by
SEED: differences of the size that another machine's float kernels (BLAS, oneDNN, kiss-icp's
parallel sums) make. A row whose figure moves far under such a nudge turns on a decision that
rounding can flip, and may not hold on another machine (fhw, once: 0.068 m on one
machine, 1.108 m on another, with the same code and model). ``bench_slam.py --nudge`` runs it.
"""

from __future__ import annotations

import runpy
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

import vgm_studio.slam.pipeline as pipeline

SIGMA = 1e-9


def nudge(seed: int) -> None:
    """Makes every SLAM run in this process nudge its odometry with ``seed``."""
    odometry = pipeline.scan_odometry

    def nudged(scans: Sequence[Any], *args: Any, **kwargs: Any) -> NDArray[np.float64]:
        poses = odometry(scans, *args, **kwargs)
        return poses + np.random.default_rng(seed).normal(0.0, SIGMA, poses.shape)

    pipeline.scan_odometry = nudged  # type: ignore[assignment]


if __name__ == "__main__":
    if len(sys.argv) < 3 or not sys.argv[1].isdigit():
        raise SystemExit(__doc__.strip().splitlines()[2])
    nudge(int(sys.argv.pop(1)))
    # The command line as ``python -m`` runs it, in this process so that the nudge holds.
    sys.argv[0] = "vgm-studio"
    runpy.run_module("vgm_studio.tools.cmd", run_name="__main__", alter_sys=True)
