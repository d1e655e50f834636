"""vgm-studio audit on graphs it did not make, with false loops injected into them.

- ``killian``: MIT's Killian Court graph (``killian.g2o`` in the PyPI package ``rtb-data``:
  3,873 poses, each with its ROBOTLASER1 scan, 3,872 sequential and 1,115 loop edges), with
  100 injected false loops per seed. Recall is the share of the injected loops flagged;
  precision the share of the flagged loops that are injected (the graph's own loops count as
  right). Own loops flagged are split by what their scans show: ``off`` where the matcher,
  started from the measurement, aligns the scans 0.3 m or 5° away from it (the reference
  labels' failure distance), else ``unexplained``.
- ``intel``: the graph ``vgm-studio slam intel.clf --g2o`` made, with 50 injected false loops,
  audited with the log's scans and scored with the Freiburg relations: the cleaned graph's
  relation error beside the input graph's and the run's.

Run: pip install rtb-data && python benchmarks/bench_audit.py [--seeds 1,2,3] [--graphs ...]

Times are wall seconds of each stage; ``judged/s`` counts edges over the validator and the
group check (the re-match of every pair from its measurement is timed apart, as matching).

Targets (issue 51): killian, seeds 1–3, recall ≥ 0.95 at precision ≥ 0.95; Intel cleaned
within 1.1× of the run without injections; ≥ 1,000 edges judged per second.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import zipfile
from pathlib import Path

from _common import REPO, datasets_dir, machine, pin_to_cores, table

from vgm_studio.audit import AuditConfig, InjectConfig, inline_input, run_audit
from vgm_studio.audit.run import AuditResult
from vgm_studio.datasets.g2o import read_graph
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.services.audit import AuditSources, run_audit_command
from vgm_studio.slam.config import ValidationConfig

OUT = REPO / "build" / "audit"


def killian_graph() -> Path:
    """killian.g2o from the installed ``rtb-data`` package, unpacked once into build/."""
    try:
        import rtbdata  # type: ignore[import-not-found]
    except ImportError:
        raise SystemExit("killian.g2o comes with rtb-data: pip install rtb-data") from None
    out = OUT / "killian.g2o"
    if not out.exists():
        OUT.mkdir(parents=True, exist_ok=True)
        packed = Path(rtbdata.__file__).parent / "data" / "killian.g2o.zip"
        with zipfile.ZipFile(packed) as z:
            out.write_bytes(z.read("killian.g2o"))
    return out


def killian_rows(seeds: list[int]) -> list[list[str]]:
    graph = read_graph(killian_graph())
    rows = []
    for seed in seeds:
        config = AuditConfig(
            validation=ValidationConfig(model=BUNDLED_MODEL),
            inject=InjectConfig(count=100, seed=seed),
        )
        start = time.perf_counter()
        result = run_audit(inline_input(graph), config, progress=False)
        wall = time.perf_counter() - start
        rows.append(_row(f"killian seed {seed}", result, wall))
        print(table(HEADER, rows[-1:]), flush=True)
    return rows


def _row(name: str, result: AuditResult, wall: float) -> list[str]:
    loops = [v for v in result.verdicts if v.edge.kind == "loop"]
    injected = [v for v in loops if v.edge.injected]
    flagged = [v for v in loops if v.decision == "flagged"]
    own = [v for v in flagged if not v.edge.injected]
    off = [v for v in own if v.rematch is not None and not v.rematch.near(_THRESHOLDS)]
    caught = sum(v.decision == "flagged" for v in injected)
    s = result.seconds
    return [
        name,
        f"{len(result.verdicts):,}",
        f"{caught}/{len(injected)}",
        f"{caught / len(injected):.3f}" if injected else "–",
        f"{caught / len(flagged):.3f}" if flagged else "–",
        f"{len(own)} ({len(off)} off)",
        f"{sum(v.decision == 'flagged' and v.edge.kind != 'loop' for v in result.verdicts)}",
        f"{s['matching']:.1f}",
        f"{s['validator']:.1f}",
        f"{s['consistency']:.1f}",
        f"{result.judged_per_second:,.0f}",
        f"{wall:.1f}",
    ]


_THRESHOLDS = ValidationConfig().thresholds
HEADER = [
    "graph",
    "edges",
    "injected flagged",
    "recall",
    "precision",
    "own loops flagged",
    "seq. flagged",
    "matching s",
    "validator s",
    "group s",
    "judged/s",
    "wall s",
]


def intel_rows(inject: int, seed: int) -> list[list[str]]:
    """The graph slam made of Intel, audited clean and with ``inject`` false loops."""
    data = datasets_dir() / "intel"
    graph = OUT / "intel.g2o"
    run = OUT / "intel-slam.json"
    if not graph.exists():
        OUT.mkdir(parents=True, exist_ok=True)
        subprocess.run(
            [sys.executable, "-m", "vgm_studio.tools.cmd", "slam", str(data / "intel.clf"),
             "--relations", str(data / "intel.relations"), "--g2o", str(graph),
             "--json", str(run)],
            check=True,
        )  # fmt: skip
    slam_after = json.loads(run.read_text())["after"]["trans_mean"] if run.exists() else None
    rows = []
    for count in (0, inject):
        config = AuditConfig(
            validation=ValidationConfig(model=BUNDLED_MODEL),
            inject=InjectConfig(count=count, seed=seed),
        )
        sources = AuditSources(graph, scans=data / "intel.clf", relations=data / "intel.relations")
        start = time.perf_counter()
        doc = run_audit_command(sources, config)
        wall = time.perf_counter() - start
        rows.append(
            [
                f"intel, {count} injected",
                f"{doc['injected_flagged']}/{doc['injected_false_loops']}",
                f"{doc['flagged_loops']}",
                f"{doc['input']['trans_mean']:.4f}",
                f"{doc['before']['trans_mean']:.4f}",
                f"{doc['after']['trans_mean']:.4f}",
                f"{doc['after']['rot_mean_deg']:.3f}",
                "–" if slam_after is None else f"{slam_after:.4f}",
                f"{doc['after']['trans_mean'] / doc['input']['trans_mean']:.3f}",
                f"{wall:.1f}",
            ]
        )
        print(table(INTEL_HEADER, rows[-1:]), flush=True)
    return rows


INTEL_HEADER = [
    "graph",
    "injected flagged",
    "loops flagged",
    "input m",
    "before m",
    "after m",
    "after °",
    "slam's after m",
    "after / input",
    "wall s",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", default="1,2,3", help="Injection seeds for killian.")
    parser.add_argument(
        "--graphs", default="killian,intel", help="Comma-separated: killian, intel (default: both)."
    )
    parser.add_argument("--intel-inject", type=int, default=50)
    args = parser.parse_args()
    graphs = set(args.graphs.split(","))
    if graphs - {"killian", "intel"}:
        parser.error(f"unknown graphs: {', '.join(sorted(graphs - {'killian', 'intel'}))}")
    try:
        seeds = [int(s) for s in args.seeds.split(",")]
    except ValueError:
        parser.error(f"--seeds takes integers separated by commas, not {args.seeds!r}")
    pin_to_cores(2)
    print(machine())
    if "killian" in graphs:
        print(table(HEADER, killian_rows(seeds)))
    if "intel" in graphs:
        print(table(INTEL_HEADER, intel_rows(args.intel_inject, 1)))


if __name__ == "__main__":
    main()
