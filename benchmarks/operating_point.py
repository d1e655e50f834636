"""The operating point SLAM needs: cuts chosen by validation precision, judged on Intel loops.

For the bundled model (or the checkpoint given), each ``--loop-precision`` p: the lowest cut
whose validation precision is ≥ p (the checkpoint's curve; what ``slam --loop-precision p``
uses), its validation precision and recall, and precision, recall and false positives on the
Intel loops (never trained on). Target (issue 12): recall ≥ 0.80 at precision ≥ 0.99 on
Intel loops. Run: python benchmarks/operating_point.py [CHECKPOINT]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from _common import machine, pin_to_cores, table
from edge_sets import test_edges

from vgm_studio.model.registry import BUNDLED_MODEL

DEFAULT = BUNDLED_MODEL
PRECISIONS = (0.95, 0.98, 0.99, 0.995)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "checkpoint", nargs="?", type=Path, default=DEFAULT, help="Model (default: bundled)."
    )
    path = parser.parse_args().checkpoint
    pin_to_cores(2)
    from vgm_studio.errors import InputError
    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.training import read_labelled
    from vgm_studio.model.validator import Validator

    try:
        validator = Validator.load(path, device="cpu")
    except InputError as exc:
        raise SystemExit(str(exc)) from None
    curve = validator.checkpoint.curve
    if curve is None:
        raise SystemExit(f"{path}: the checkpoint keeps no validation curve")
    test = read_labelled([test_edges()], progress=False, context=validator.context)
    probs = validator.predict_samples(test.samples)
    cuts = [(f"{p}", validator.threshold_at_precision(p)) for p in PRECISIONS]
    rows = []
    for name, cut in [*cuts, ("(checkpoint threshold)", validator.threshold)]:
        at = np.flatnonzero(np.asarray(curve.thresholds) >= cut)
        k = int(at[0]) if len(at) else len(curve.thresholds) - 1
        m = binary_metrics(test.labels, probs, cut)
        rows.append(
            [
                name,
                f"{cut:.3f}",
                f"{curve.precision[k]:.3f} / {curve.recall[k]:.3f}",
                f"{m['precision']:.3f} / {m['recall']:.3f}",
                str(m["fp"]),
            ]
        )
    print(f"# {path.name} on {len(test.labels)} Intel loops; cuts from its validation curve")
    print(f"# {machine()}")
    header = ["--loop-precision", "cut p(success)", "validation P / R", "Intel P / R", "Intel FP"]
    print(table(header, rows))


if __name__ == "__main__":
    sys.exit(main())
