"""Matcher accuracy on simulated pairs whose guess is within 0.2 m and 5° of the truth.

Target: median error ≤ 1 cm and ≤ 0.2°. kiss-icp alone is shown beside kiss-icp + the 2D
refinement. Run: python benchmarks/bench_matching.py
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import machine, pin_to_cores, table

PRESETS = ("office", "repetitive", "loop", "l-junction", "t-junction", "corridor")
PAIRS = 200


def main() -> None:
    pin_to_cores(1)
    from vgm_studio.core import se2
    from vgm_studio.datasets import open_log
    from vgm_studio.matching.config import MatchConfig
    from vgm_studio.matching.matcher import ScanMatcher
    from vgm_studio.simulation.simulate import SimConfig, simulate

    rows = []
    pooled: dict[str, list[tuple[float, float]]] = {"kiss-icp": [], "kiss-icp + 2D": []}
    with tempfile.TemporaryDirectory() as tmp:
        for preset in PRESETS:
            log = open_log(simulate(SimConfig(preset=preset, seed=11), Path(tmp)))
            ref = log.reference_poses()
            rng = np.random.default_rng(0)
            cases = []
            for _ in range(PAIRS):
                a = int(rng.integers(0, len(log) - 20))
                b = a + int(rng.integers(1, 20))
                truth = se2.between(ref[a], ref[b])
                r, phi = rng.uniform(0, 0.2), rng.uniform(0, 2 * np.pi)
                off = [r * np.cos(phi), r * np.sin(phi), np.radians(rng.uniform(-5, 5))]
                cases.append((a, b, truth, truth + off))
            for name, config in (
                ("kiss-icp", MatchConfig(refine=False)),
                ("kiss-icp + 2D", MatchConfig()),
            ):
                matcher = ScanMatcher(config)
                errs, secs = [], []
                for a, b, truth, guess in cases:
                    t = time.perf_counter()
                    est = matcher.match(log.scans[a], log.scans[b], guess).estimate
                    secs.append(time.perf_counter() - t)
                    errs.append(se2.pose_error(truth, est))
                pooled[name] += errs
                rows.append(_row(preset, name, np.array(errs), float(np.median(secs))))
    for name, errs in pooled.items():
        rows.append(_row("all presets", name, np.array(errs), float("nan")))
    print(
        f"# {PAIRS} pairs per preset (seed 11), scans 1–19 apart, guess ≤ 0.2 m / 5° off, "
        "361 beams, 1 cm range noise, 1 core"
    )
    print(f"# {machine()}")
    print(
        table(
            ["world", "matcher", "median cm", "median °", "p90 cm", "≤10 cm & 2°", "ms/pair"], rows
        )
    )
    best = next(r for r in rows if r[0] == "all presets" and r[1] == "kiss-icp + 2D")
    met = float(best[2]) <= 1.0 and float(best[3]) <= 0.2
    print(f"target median ≤ 1 cm and ≤ 0.2° (all presets): {'met' if met else 'MISSED'}")


def _row(world: str, name: str, e: np.ndarray, sec: float) -> list[str]:
    ok = np.mean((e[:, 0] <= 0.10) & (np.degrees(e[:, 1]) <= 2.0))
    return [
        world,
        name,
        f"{100 * np.median(e[:, 0]):.2f}",
        f"{np.degrees(np.median(e[:, 1])):.3f}",
        f"{100 * np.percentile(e[:, 0], 90):.1f}",
        f"{100 * ok:.0f}%",
        "" if np.isnan(sec) else f"{1e3 * sec:.2f}",
    ]


if __name__ == "__main__":
    sys.exit(main())
