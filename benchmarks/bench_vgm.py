"""pair_map speed: two 360-point scans on one core, beside the plain per-cell loop.

Target: median ≤ 1 ms. Run: python benchmarks/bench_vgm.py
"""

from __future__ import annotations

import importlib.util
import sys

from _common import REPO, datasets_dir, machine, median_time, pin_to_cores, table


def _plain_loop():
    # The loop the tests check against, so both measure the same definition.
    spec = importlib.util.spec_from_file_location("test_vgm", REPO / "tests" / "test_vgm.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.plain_grid_map


def main() -> None:
    pin_to_cores(1)
    from vgm_studio.core import se2
    from vgm_studio.datasets import open_log
    from vgm_studio.vgm import pair_map

    plain = _plain_loop()
    log = open_log(datasets_dir() / "radish-corrected" / "belgioioso-corrected.log")
    a, b = log.scans[100], log.scans[101]
    prev, cur = a.points()[:360], b.points()[:360]
    est = se2.between(a.reference, b.reference)
    fast = median_time(lambda: pair_map(prev, cur, est), repeat=500)

    def loop() -> None:
        plain(prev)
        plain(se2.transform_points(est, cur))

    slow = median_time(loop, repeat=10, warmup=1)
    print(f"# pair_map, {len(prev)} + {len(cur)} points (belgioioso scans 100/101), 1 core")
    print(f"# {machine()}")
    print(
        table(
            ["implementation", "median ms", "vs loop"],
            [
                ["pair_map (numpy)", f"{fast * 1e3:.3f}", f"{slow / fast:.0f}× faster"],
                ["plain per-cell loop", f"{slow * 1e3:.1f}", "1×"],
            ],
        )
    )
    print(f"target median ≤ 1 ms: {'met' if fast <= 1e-3 else 'MISSED'}")


if __name__ == "__main__":
    sys.exit(main())
