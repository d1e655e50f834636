"""vgm-studio fleet on the ten corrected radish logs and Intel: 1 worker against 2, same figures.

Each fleet run starts its own local Ray with two CPUs (its start-up timed apart), runs every
log of the manifest through candidates, validation and SLAM, and writes its table under
build/fleet/. Throughput is logs per minute of the fleet run; the ratio is two workers
against one. Then each log's SLAM figures in the two-worker run are compared with a
``vgm-studio slam --json`` run of the same log in this process (counts exactly, errors to a
relative 1e-6; timings left out).

Run: python benchmarks/bench_fleet.py [--logs orebro,edmonton] [--max 2000] [--no-check]

Target (issue 15): throughput with two workers ≥ 1.6× one worker (logs/min); the per-log
figures equal the single-log commands' figures.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _common import REPO, datasets_dir, machine, table

from vgm_studio.matching.candidates import CandidateConfig
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.services.fleet import RayOptions, run_fleet
from vgm_studio.services.fleet_log import FleetSettings
from vgm_studio.slam.config import SlamConfig, ValidationConfig

OUT = REPO / "build" / "fleet"
TARGET_RATIO = 1.6
TIMING = {"seconds", "stage_seconds", "settings"}


def manifest(names: list[str] | None, folder: Path) -> Path:
    """The corrected radish logs (their own poses label the candidates) and raw Intel."""
    data = datasets_dir()
    lines = [
        {"log": str(p), "name": p.name.removesuffix("-corrected.log")}
        for p in sorted((data / "radish-corrected").glob("*-corrected.log"))
    ]
    intel = data / "intel"
    relations = str(intel / "intel.relations")
    lines.append({"log": str(intel / "intel.clf"), "relations": relations, "name": "intel"})
    if names:
        lines = [d for d in lines if d["name"] in names]
    path = folder / "fleet.jsonl"
    path.write_text("".join(json.dumps(d) + "\n" for d in lines))
    return path


def fleet_run(path: Path, settings: FleetSettings, workers: int) -> tuple[Any, float, float]:
    """A fleet run on a fresh local Ray: the run, Ray's start-up and the fleet's seconds."""
    import ray

    out = OUT / f"workers-{workers}"
    shutil.rmtree(out, ignore_errors=True)  # a throughput run skips nothing
    ray_dir = Path(tempfile.mkdtemp(prefix="vgmray", dir="/tmp"))
    start = time.perf_counter()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, _temp_dir=str(ray_dir))
    started = time.perf_counter()
    try:
        run = run_fleet(path, out, settings, RayOptions(workers=workers), progress=False)
    finally:
        ray.shutdown()
    return run, started - start, time.perf_counter() - started


def same_figures(row: dict[str, Any], tmp: Path) -> str:
    """'yes' when ``vgm-studio slam --json`` on the log gives the fleet's SLAM figures."""
    single = tmp / f"{row['name']}.json"
    args = ["slam", row["log"], "--json", str(single)]
    if row["relations"]:
        args += ["--relations", row["relations"]]
    # The command itself, as a user runs it: the benchmark compares against the CLI's output.
    subprocess.run([sys.executable, "-m", "vgm_studio.tools.cmd", *args], check=True)
    a = json.loads(Path(row["slam_json"]).read_text())
    b = json.loads(single.read_text())
    for key in set(a) | set(b):
        if key in TIMING:
            continue
        va, vb = a.get(key), b.get(key)
        if isinstance(vb, dict) and isinstance(va, dict):
            bad = [k for k in vb if not _close(va.get(k), vb[k])]
            if bad:
                return f"no ({key}.{bad[0]}: {va.get(bad[0])} vs {vb[bad[0]]})"
        elif not _close(va, vb):
            return f"no ({key}: {va} vs {vb})"
    return "yes"


def _close(a: Any, b: Any) -> bool:
    """Equal, floats to a relative 1e-6 (p(success) is float32 arithmetic whose summation
    order follows torch's thread count: a worker runs one thread, the command two), inside
    lists and dicts too (the per-edge records)."""
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b) <= 1e-6 * max(abs(a), abs(b), 1e-12)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    return bool(a == b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", help="comma-separated names (default: all eleven)")
    parser.add_argument("--max", type=int, default=2000, help="loop candidates per log")
    parser.add_argument("--no-check", action="store_true", help="skip the single-log runs")
    args = parser.parse_args()
    # Two cores, but no thread-count variables: Ray gives each one-CPU worker one thread.
    os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:2])
    OUT.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    path = manifest(args.logs.split(",") if args.logs else None, tmp)
    settings = FleetSettings(
        slam=SlamConfig(validation=ValidationConfig(model=BUNDLED_MODEL)),
        candidates=CandidateConfig(keyframe_distance=0.5, max_loops=args.max),
    )
    runs = {w: fleet_run(path, settings, w) for w in (1, 2)}
    n = len(runs[2][0].rows)
    speed = {w: 60 * n / seconds for w, (_, _, seconds) in runs.items()}
    rows = []
    for row, one in zip(runs[2][0].rows, runs[1][0].rows, strict=True):
        # The run with two workers is checked; the one-worker run must agree with it too.
        agree = one["status"] != "done" or one["loops_kept"] == row["loops_kept"]
        done = row["status"] == "done"
        err = row.get("after_trans_mean_m")
        rows.append([
            row["name"], str(row["scans"]) if done else "failed", str(row.get("candidates") or "–"),
            f"{row['loops_kept']}/{row['loops_total']}" if done else "–",
            f"{err:.4f}" if err is not None else "–",
            f"{one['seconds']:.0f}" if one.get("seconds") else "–",
            f"{row['seconds']:.0f}" if row.get("seconds") else "–",
            (same_figures(row, tmp) if done and not args.no_check else "not checked")
            + ("" if agree else " (1 worker differs)"),
        ])  # fmt: skip
    header = ["log", "scans", "candidates", "loops kept", "after m", "s (1 worker)",
              "s (2 workers)", "= slam --json"]  # fmt: skip
    ratio = speed[2] / speed[1]
    print(f"# {n} logs, --max {args.max}, candidates every 0.5 m, vgmnet; local Ray, 2 CPUs")
    print(f"# {machine()}")
    print(table(header, rows))
    for w, (run, start_up, seconds) in runs.items():
        print(
            f"{w} worker(s): {seconds:.0f} s for the fleet ({start_up:.0f} s Ray start-up "
            f"before it), {speed[w]:.2f} logs/min ({run.table})"
        )
    verdict = "met" if ratio >= TARGET_RATIO else "not met"
    print(f"ratio 2 workers / 1 worker: {ratio:.2f} (target ≥ {TARGET_RATIO}): {verdict}")


if __name__ == "__main__":
    main()
