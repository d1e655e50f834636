"""Candidate generation speed on intel.gfs.log (910 scans, 2000 loop candidates).

Target: ≥ 200 edges per second. Also reports the label mix. Run:
python benchmarks/bench_candidates.py
"""

from __future__ import annotations

import sys
import time
from collections import Counter

from _common import datasets_dir, machine, pin_to_cores, table


def main() -> None:
    pin_to_cores(2)
    from vgm_studio.datasets import open_log
    from vgm_studio.matching.candidates import CandidateConfig, make_candidates
    from vgm_studio.matching.matcher import ScanMatcher

    path = datasets_dir() / "intel" / "intel.gfs.log"
    t0 = time.perf_counter()
    log = open_log(path)
    t_read = time.perf_counter() - t0
    rows = []
    for name, config in [
        ("loops only (2000)", CandidateConfig(sequential=False)),
        ("sequential + loops", CandidateConfig()),
    ]:
        t = time.perf_counter()
        edges = make_candidates(log, ScanMatcher(), config, progress=False)
        dt = time.perf_counter() - t
        labels = Counter(e.label for e in edges)
        rows.append(
            [
                name,
                str(len(edges)),
                f"{dt:.2f}",
                f"{len(edges) / dt:.0f}",
                f"{labels['success']}/{labels['failure']}/{labels['ambiguous']}",
            ]
        )
    print(f"# candidates on {path.name} ({len(log)} scans, read in {t_read:.2f} s), 2 cores")
    print(f"# {machine()}")
    print(table(["edges", "count", "seconds", "edges/s", "success/failure/ambiguous"], rows))


if __name__ == "__main__":
    sys.exit(main())
