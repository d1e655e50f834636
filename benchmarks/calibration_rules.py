"""Which validation edges should choose a model's cut? Both rules, on every held-out building.

For each fold model that ``bench_generalisation.py`` trained (build/edges/folds), its
validation split is made again and its cut chosen twice: on every validation edge (simulated
worlds' included), and on the real logs' edges alone (``model/calibration.py``, the rule
training now uses). Each is judged on the held-out building's loops: accuracy at the
accuracy cut, and recall (with precision) at the cut the validation curve picks for
precision 0.99. Weights are not touched; nothing is trained.

Run: python benchmarks/calibration_rules.py [--models vgmnet,rgb-baseline,score]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from _common import machine, pin_to_cores, table
from bench_generalisation import BUILD, MODELS, buildings, subset
from folds import make_folds
from recalibrate import validation_rows


def _judge(labels, probs, test_labels, test_probs) -> tuple[float, str]:
    from vgm_studio.model.fitting import choose_threshold
    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.operating import precision_curve, threshold_for_precision

    accuracy = binary_metrics(test_labels, test_probs, choose_threshold(labels, probs))
    cut = threshold_for_precision(precision_curve(labels, probs), 0.99)
    if cut is None:
        return accuracy["accuracy"], "—"
    m = binary_metrics(test_labels, test_probs, cut)
    return accuracy["accuracy"], f"{m['recall']:.3f} (P {m['precision']:.3f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--models", default=",".join(MODELS))
    args = parser.parse_args()
    pin_to_cores(2)
    from vgm_studio.model.checkpoint import load_checkpoint
    from vgm_studio.model.training import read_labelled
    from vgm_studio.model.validator import Validator

    made, sims = buildings([])
    names = [b.name for b in made]
    folds = make_folds(made, sims, names)
    files = sorted({p for f in folds for p in f.train} | {f.test for f in folds})
    data = read_labelled(files, progress=False)
    origin = [f["path"] for f in data.files for _ in range(f["used"])]
    rows, totals = [], {}
    for fold in folds:
        training = subset(data, origin, fold.train)
        test = subset(data, origin, [fold.test])
        for model in args.models.split(","):
            path = BUILD / "folds" / f"{fold.held_out}-{model}.pt"
            if not path.exists():
                continue
            labels, probs, real = validation_rows(path, load_checkpoint(path), training)
            test_probs = Validator.load(path, device="cpu").predict_samples(test.samples)
            all_acc, all_rec = _judge(labels, probs, test.labels, test_probs)
            real_acc, real_rec = _judge(labels[real], probs[real], test.labels, test_probs)
            totals.setdefault(model, []).append((all_acc, real_acc))
            rows.append(
                [fold.held_out, model, f"{all_acc:.4f}", f"{real_acc:.4f}", all_rec, real_rec]
            )
            print(" | ".join(rows[-1]), flush=True)
    print(f"\n# cut chosen on all validation edges or on real logs' ones; {machine()}")
    header = ["held out", "model", "accuracy (all)", "accuracy (real)"]
    header += ["recall @ P≥0.99 cut (all)", "recall @ P≥0.99 cut (real)"]
    print(table(header, rows))
    for model, pairs in totals.items():
        mean = np.mean(pairs, axis=0)
        print(f"{model}: mean accuracy {mean[0]:.4f} (all) against {mean[1]:.4f} (real)")


if __name__ == "__main__":
    sys.exit(main())
