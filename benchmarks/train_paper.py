"""Trains the paper's VGM-Net (``vgmnet-paper``) on the full training set and ships it.

One command: python benchmarks/train_paper.py [--device cuda] [--epochs N] [--epoch-size N]
The layers are the paper's (1×1 conv 16, conv 32/64/128/128, MLP 256, sigmoid; Adam, batch
128) over the whole 400×400 VGM, on the edges the default model learns from (edge_sets.py:
the ten corrected buildings and the simulated worlds; never Intel). What makes it affordable
on a CPU: the network takes each batch's occupied cells, so its 1×1 stem and first strided
block cost what the ~0.4% occupied cells cost (``VGMNetPaper.forward_cells``, the same
function), channels-last convolutions, two threads. The run writes its state after each
epoch: stopped, the same command goes on where it was. Before each validation batch norm's
statistics are recomputed over 30 batches of training draws (``--bn-batches``,
``model/precise_bn.py``): the running averages lag a network that moves fast, and
judged with them the paper's network looked like chance mid-run. The checkpoint (1.3 MB) is
copied to assets/models/vgmnet-paper.pt.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time

from _common import REPO, pin_to_cores
from edge_sets import training_edges

BUILT = REPO / "build" / "models" / "vgmnet-paper.pt"
SHIPPED = REPO / "assets" / "models" / "vgmnet-paper.pt"
MAX_MB = 30


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--device", default="cpu", help="cpu, cuda or auto.")
    parser.add_argument("--epochs", type=int, default=5)
    parser.add_argument("--epoch-size", type=int, default=6144, help="Draws per epoch.")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads.")
    parser.add_argument("--lr", type=float, default=2e-3, help="Peak learning rate.")
    parser.add_argument(
        "--more", action="store_true", help="Go on from the shipped weights: a second schedule."
    )
    parser.add_argument(
        "--bn-batches",
        type=int,
        default=30,
        help="Batches batch norm's statistics are recomputed over before each validation.",
    )
    args = parser.parse_args()
    if args.device == "cpu":
        pin_to_cores(args.threads)
    files = training_edges()
    BUILT.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    command = [sys.executable, "-m", "vgm_studio.tools.cmd", "train", *map(str, files)]
    command += ["--model", "vgmnet-paper", "--batch-size", "128", "--patience", "99"]
    command += ["--epochs", str(args.epochs), "--epoch-size", str(args.epoch_size)]
    command += ["--device", args.device, "--threads", str(args.threads), "--out", str(BUILT)]
    command += ["--lr", str(args.lr), "--bn-batches", str(args.bn_batches)]
    command += ["--init", str(SHIPPED)] if args.more else []
    subprocess.run(command, check=True)
    minutes = (time.perf_counter() - start) / 60
    size = BUILT.stat().st_size / 1e6
    if size <= MAX_MB:
        shutil.copyfile(BUILT, SHIPPED)
    print(
        f"trained {BUILT.relative_to(REPO)} in {minutes:.1f} min this run on {args.device} "
        f"({args.epochs} epochs × {args.epoch_size} draws); {size:.2f} MB"
        + (f", copied to {SHIPPED.relative_to(REPO)}" if size <= MAX_MB else ", too big to ship")
    )


if __name__ == "__main__":
    sys.exit(main())
