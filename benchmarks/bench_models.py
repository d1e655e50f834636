"""Every validator side by side on the same Intel test edges, the paper's figures beside them.

Trains what is missing into build/models (the vgmnet and vgmnet-paper rows are the shipped
models, made by train_default.py and train_paper.py), evaluates on the Intel loops, and times
CPU inference per pair on two cores at batch 64, VGM construction included.
Run: python benchmarks/bench_models.py [--retrain]

Targets (issue 3): vgmnet accuracy ≥ 0.90 and F1 ≥ 0.90, ahead of rgb-baseline and score;
≥ 200 pairs/s; training the default ≤ 15 minutes on two CPU cores.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

from _common import REPO, RGB_CPU_RECIPE, machine, pin_to_cores, table
from edge_sets import test_edges, training_edges

from vgm_studio.model.registry import BUNDLED_MODEL

MODELS = REPO / "build" / "models"
DEFAULT = BUNDLED_MODEL
# The shipped models and the scripts that make them.
SHIPPED = {"vgmnet": DEFAULT, "vgmnet-paper": REPO / "assets" / "models" / "vgmnet-paper.pt"}
MAKERS = {"vgmnet": "train_default.py", "vgmnet-paper": "train_paper.py"}
PAPER_FIGURES = {
    "vgmnet": ("VGM-Net (paper, Intel)", 0.8071),
    "rgb-baseline": ("Jeong and Lee baseline (paper, Intel)", 0.6877),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--retrain", action="store_true", help="Train again even if present.")
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    pin_to_cores(2)
    import torch

    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.training import TrainConfig, read_labelled, train
    from vgm_studio.model.validator import Validator

    test = read_labelled([test_edges()], progress=False)
    data = None
    rows = []
    # "score + spread": the score baseline given the same match spread that vgmnet reads.
    for name, model, hyper in (
        ("vgmnet", "vgmnet", {}),
        ("vgmnet-paper", "vgmnet-paper", {}),
        ("rgb-baseline", "rgb-baseline", {}),
        ("score", "score", {}),
        ("score + spread", "score", {"spread": True}),
    ):
        path = SHIPPED.get(name, MODELS / f"{name.replace(' + ', '-')}.pt")
        if name in SHIPPED and not path.exists():
            raise SystemExit(f"{path} missing: run python benchmarks/{MAKERS[name]}")
        if name not in SHIPPED and (args.retrain or not path.exists()):
            data = data or read_labelled(training_edges(), progress=False)
            gpu = args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available())
            config = TrainConfig(model=model, hyper=hyper, device=args.device)
            if not gpu and model == "rgb-baseline":
                epochs, epoch_size = RGB_CPU_RECIPE
                config = replace(config, epochs=epochs, epoch_size=epoch_size)
            train(data, config, path, progress=False, log=print)
        v = Validator.load(path, device="cpu")
        probs = v.predict_samples(test.samples)
        m = binary_metrics(test.labels, probs, v.threshold)
        timed = test.samples[: 128 if name == "vgmnet-paper" else 640]
        v.predict_samples(timed[:64])
        t = time.perf_counter()
        v.predict_samples(timed, batch_size=64)
        per_pair = (time.perf_counter() - t) / len(timed)
        trained = v.checkpoint.training
        counts = trained["counts"]["train"]
        subset_note = "" if trained["config"].get("max_train") is None else " (subset)"
        rows.append(
            [
                name,
                f"{m['accuracy']:.4f}",
                f"{m['precision']:.4f}",
                f"{m['recall']:.4f}",
                f"{m['f1']:.4f}",
                f"{m['auc']:.4f}",
                f"{m['tp']}/{m['fp']}/{m['tn']}/{m['fn']}",
                f"{1e3 * per_pair:.2f}",
                f"{1 / per_pair:.0f}",
                f"{counts['success'] + counts['failure']}{subset_note}",
                f"{trained['seconds'] / 60:.1f} ({v.checkpoint.device})",
            ]
        )
        if name in PAPER_FIGURES:
            label, acc = PAPER_FIGURES[name]
            rows.append([label, f"{acc:.4f}", "", "", "", "", "", "", "", "", ""])
    print(
        f"# test: {Path(test_edges()).name}: {len(test.labels)} Intel loops "
        f"({int(test.labels.sum())} success, {int((~test.labels).sum())} failure), never "
        "trained on; inference on 2 CPU cores, batch 64, VGMs included"
    )
    print(f"# {machine()}")
    print(
        table(
            [
                "model",
                "accuracy",
                "precision",
                "recall",
                "F1",
                "AUC",
                "TP/FP/TN/FN",
                "ms/pair",
                "pairs/s",
                "train edges",
                "train min (device)",
            ],
            rows,
        )
    )


if __name__ == "__main__":
    sys.exit(main())
