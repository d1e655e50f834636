"""Validators judged on the loops a SLAM run meets, before one replaces the bundled model.

``bench_slam.py --model`` runs SLAM with another validator, but a run is chaotic: one loop
decided otherwise early on sends a large building's run elsewhere, so its table cannot tell a
worse validator from a different path. This script holds the loops still. It runs ``vgm-studio
slam --loops-out`` once per building with the bundled model (cached in build/slam-loops/<the
bundled model's hash>, so a new bundled model makes them again) and judges every matched loop
with each checkpoint given: per building, the right loops and the wrong ones (against the
corrected poses) passed at the SLAM run's loop bar, and the AUC. The Freiburg hospital has no
reference and, as far as its path shows, almost no revisit: its row counts the loops passed,
which are mostly corridor aliases.

The benchmark loops (``bench_generalisation.py``) are reference poses nudged by random
guesses; these are what place recognition and the window search propose, aliases included.
A model can rank the first better and pass more of the second's wrong loops.

Run: python benchmarks/slam_loops.py [MODEL.pt ...] [--bar P]   (default: the SLAM run's bar)
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np
from _common import REPO, datasets_dir, machine, pin_to_cores, table
from bench_slam import CORRECTED, arguments, failure

from vgm_studio.model.registry import BUNDLED_MODEL

OUT = REPO / "build" / "slam-loops"
BUNDLED = BUNDLED_MODEL
ROWS = (*CORRECTED, "fr-clinic")  # bench_slam.py's rows with a building's own loops


def loops_file(name: str, out: Path) -> Path:
    """The loops the bundled model's run of bench_slam.py's row ``name`` matched, made in
    ``out`` on first use."""
    path = out / f"{name}.jsonl"
    if not path.exists():
        out.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(
            [sys.executable, "-m", "vgm_studio.tools.cmd", "slam", "--loops-out", str(path),
             *map(str, arguments(name, out / f"{name}.json", pictures=False))],
            capture_output=True, text=True,
        )  # fmt: skip
        if done.returncode != 0:
            raise SystemExit(f"{name}: slam failed: {failure(done.stderr)}")
    return path


def _judged(p: np.ndarray, labels: np.ndarray, bar: float) -> str:
    from vgm_studio.model.metrics import binary_metrics

    known = np.isin(labels, ["success", "failure"])
    if not known.any():
        return f"{int((p >= bar).sum())} of {len(p)} passed"
    y, q = labels[known] == "success", p[known]
    right, wrong = int(((q >= bar) & y).sum()), int(((q >= bar) & ~y).sum())
    return f"{right} / {wrong} / {binary_metrics(y, q, bar)['auc']:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("models", nargs="*", type=Path, help="Checkpoints (default: bundled).")
    parser.add_argument("--bar", type=float, default=None, help="Loop bar (default: slam's).")
    args = parser.parse_args()
    models = args.models or [BUNDLED]
    for m in models:
        if not m.is_file():
            raise SystemExit(f"{m}: no such checkpoint")
    datasets_dir()  # the scans of every loop are read from the logs, cached or not
    pin_to_cores(2)
    from vgm_studio.core.hashing import content_hash
    from vgm_studio.errors import InputError
    from vgm_studio.matching.edge_scans import EdgeScans
    from vgm_studio.matching.edges import read_edges
    from vgm_studio.model.validator import Validator
    from vgm_studio.slam.config import ValidationConfig

    bar = args.bar if args.bar is not None else ValidationConfig().loop_threshold
    if bar is None:
        raise SystemExit("slam has no fixed loop bar by default: give --bar")
    out = OUT / content_hash(BUNDLED)[:12]
    try:
        validators = [Validator.load(m, device="cpu") for m in models]
    except InputError as exc:
        raise SystemExit(str(exc)) from None
    rows = []
    scans = EdgeScans()  # each log read once, whatever each model draws from it
    for name in ROWS:
        edges = read_edges(loops_file(name, out))
        labels = np.array([e.label or "" for e in edges], dtype=object)
        right, wrong = int((labels == "success").sum()), int((labels == "failure").sum())
        counts = f"{right} / {wrong}" if right + wrong else f"{len(edges)} (no reference)"
        # Each model reads the loops as it was trained to (its own context, model/context.py).
        judged = [_judged(v.predict(edges, scans), labels, bar) for v in validators]
        rows.append([name, counts, *judged])
    print(f"# loops the bundled model's SLAM runs matched ({out.name}), judged at p ≥ {bar}")
    print(f"# {machine()}")
    header = ["building", "loops right / wrong"]
    header += [f"{m.stem}: right / wrong passed / AUC" for m in models]
    print(table(header, rows))


if __name__ == "__main__":
    sys.exit(main())
