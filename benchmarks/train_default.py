"""Trains the bundled default model, assets/models/vgmnet-default.pt, from scratch.

One command: python benchmarks/train_default.py [--context N] [--[no-]covisible] [--out PATH]
It builds the training edge sets if they are missing (see edge_sets.py: the ten corrected
buildings and the simulated worlds; never Intel), then runs ``vgm-studio train`` with the
defaults on two CPU cores, and prints the wall time beside the 15-minute target. Unasked,
the pairs are drawn as ``vgm-studio train`` draws them (``model.context.DEFAULT_CONTEXT``);
``--context``/``--covisible`` train a candidate of another recipe.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from _common import REPO, pin_to_cores
from edge_sets import training_edges

from vgm_studio.model.registry import BUNDLED_MODEL

OUT = BUNDLED_MODEL


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--context", type=int, help="train --context (unset: its default).")
    parser.add_argument(
        "--covisible",
        action=argparse.BooleanOptionalAction,
        help="train --covisible / --no-covisible (unset: its default).",
    )
    parser.add_argument("--out", type=Path, default=OUT, help="Where the checkpoint goes.")
    args = parser.parse_args()
    out = args.out.resolve()
    pin_to_cores(2)
    # Sorted, as bench_generalisation.py reads them: its Intel fold is this same training.
    files = sorted(training_edges())
    start = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "vgm_studio.tools.cmd",
            "train",
            *map(str, files),
            "--model",
            "vgmnet",
            "--device",
            "cpu",
            *([] if args.context is None else ["--context", str(args.context)]),
            *(
                []
                if args.covisible is None
                else ["--covisible" if args.covisible else "--no-covisible"]
            ),
            "--out",
            str(out),
        ],
        check=True,
    )
    minutes = (time.perf_counter() - start) / 60
    shown = out.relative_to(REPO) if out.is_relative_to(REPO) else out
    print(
        f"trained {shown} in {minutes:.1f} min on 2 CPU cores "
        f"(target ≤ 15 min: {'met' if minutes <= 15 else 'MISSED'}); "
        f"{out.stat().st_size / 1e6:.2f} MB"
    )


if __name__ == "__main__":
    sys.exit(main())
