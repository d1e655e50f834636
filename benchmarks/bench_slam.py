"""vgm-studio slam on the raw Intel log: every validator, with and without GNC, side by side.

Each row is one whole run of the command on two cores (odometry, front end, both graphs,
maps, JSON and a rerun recording), scored with the Freiburg relations (Kümmerle et al. 2009).
The rgb-baseline and score checkpoints are the model benchmark's (build/models, trained here
with bench_models.py's CPU settings when missing); vgmnet is the bundled default; reference
validates against GMapping's corrected poses (intel.gfs.log).

Run: python benchmarks/bench_slam.py [--only vgmnet] [--no-gnc]

Targets (issue 4): with --validator vgmnet, mean translational error ≤ 0.05 m and the whole
run ≤ 300 s on two CPU cores. Anchors (Kümmerle et al. 2009, Intel): scan matching alone
0.220 m, graph mapping 0.031 m.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from _common import REPO, datasets_dir, machine, pin_to_cores, table

from vgm_studio.slam.config import VALIDATORS as SLAM_VALIDATORS

OUT = REPO / "build" / "slam"
MODELS = REPO / "build" / "models"
GFS_OFFSET = "976052857.33753"  # intel.gfs.log counts from the start of intel.clf
VALIDATORS = SLAM_VALIDATORS  # every validator the run knows, from the model registry
TARGET_M, TARGET_S = 0.05, 300.0

# Runs the command in a fresh process; registers it on the CLI if the app does not yet.


def _model(name: str) -> Path:
    """The model benchmark's checkpoint, trained with its CPU settings when missing."""
    path = MODELS / f"{name}.pt"
    if path.exists():
        return path
    from edge_sets import training_edges

    from vgm_studio.model.training import TrainConfig, read_labelled, train

    data = read_labelled(training_edges(), progress=False)
    slow = name == "rgb-baseline"
    config = TrainConfig(
        model=name,
        device="cpu",
        epochs=6 if slow else 12,
        epoch_size=3000 if slow else 6000,
    )
    train(data, config, path, progress=False, log=print)
    return path


def run(validator: str, robust: str) -> dict:
    intel = datasets_dir() / "intel"
    tag = f"{validator}-{robust}"
    args = [
        "slam", intel / "intel.clf",
        "--validator", validator,
        "--robust", robust,
        "--relations", intel / "intel.relations",
        "--json", OUT / f"{tag}.json",
        "--map-png", OUT / f"maps-{tag}",
        "--record", OUT / f"{tag}.rrd",
    ]  # fmt: skip
    if validator in ("rgb-baseline", "score"):
        args += ["--model", _model(validator)]
    if validator == "reference":
        args += ["--reference", intel / "intel.gfs.log", "--time-offset", GFS_OFFSET]
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "vgm_studio.tools.cmd", *map(str, args)],
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"{tag} failed:\n{proc.stderr[-2000:]}")
    doc = json.loads((OUT / f"{tag}.json").read_text())
    doc["wall"] = wall
    doc["rrd_mb"] = (OUT / f"{tag}.rrd").stat().st_size / 1e6
    return doc


def row(validator: str, robust: str, d: dict) -> list[str]:
    b, a = d["before"], d["after"]
    return [
        validator,
        robust,
        f"{b['trans_mean']:.4f} ± {b['trans_std']:.4f}",
        f"{a['trans_mean']:.4f} ± {a['trans_std']:.4f}",
        f"{a['rot_mean_deg']:.3f} ± {a['rot_std_deg']:.3f}",
        f"{d['loops_kept']}/{d['loops_total']}",
        f"{d['edges_kept']}/{d['edges_rejected']}",
        str(d["gnc_rejected"]["after"]) if robust == "gnc" else "",
        f"{d['wall']:.0f}",
        f"{d['rrd_mb']:.0f}",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--only", choices=VALIDATORS, action="append")
    parser.add_argument("--no-gnc", action="store_true", help="Skip the --robust gnc runs.")
    args = parser.parse_args()
    pin_to_cores(2)
    OUT.mkdir(parents=True, exist_ok=True)
    rows, results = [], {}
    for validator in args.only or VALIDATORS:
        for robust in ("none",) if args.no_gnc else ("none", "gnc"):
            d = run(validator, robust)
            results[(validator, robust)] = d
            rows.append(row(validator, robust, d))
            print(
                f"{validator} {robust}: {d['after']['trans_mean']:.4f} m, {d['wall']:.0f} s",
                file=sys.stderr,
            )
    first = next(iter(results.values()))
    print(
        f"# intel.clf ({first['scans']} scans, {first['keyframes']} keyframes) with "
        "intel.relations; whole runs (maps, JSON, recording) on 2 cores"
    )
    print(f"# {machine()}")
    print(
        table(
            [
                "validator",
                "robust",
                "before m (mean ± std)",
                "after m (mean ± std)",
                "after ° (mean ± std)",
                "loops kept",
                "edges kept/rejected",
                "GNC rejected",
                "wall s",
                "rrd MB",
            ],
            rows,
        )
    )
    print("anchors (Kümmerle et al. 2009, Intel): scan matching 0.220 m, graph mapping 0.031 m")
    target = results.get(("vgmnet", "none"))
    if target is not None:
        err, wall = target["after"]["trans_mean"], target["wall"]
        met = err <= TARGET_M and wall <= TARGET_S
        print(
            f"target vgmnet ≤ {TARGET_M} m and ≤ {TARGET_S:.0f} s: {err:.4f} m, {wall:.0f} s: "
            + ("met" if met else "NOT met")
        )


if __name__ == "__main__":
    sys.exit(main())
