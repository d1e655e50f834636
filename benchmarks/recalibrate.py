"""Chooses a checkpoint's cut and precision curve again, by the calibration rule, without
retraining.

Checkpoints written before ``model/calibration.py`` chose their cut on every validation edge,
simulated worlds' included; this script applies the rule (real logs' validation edges when
each class has enough) to them. Their validation split is reproducible: the training files
they record (found by name among the current edge sets when the recorded path is gone; the
simulated worlds' files differ only in the folder they name) and ``stratified_split`` with
the recorded fraction and seed. The script checks that the split's class counts and the
confusion counts at the recorded cut come out again, then writes the new cut, figures and
curve, leaving the weights bit for bit as they were (a hash of the state dict before and
after).

Run: python benchmarks/recalibrate.py [CHECKPOINT ...]   (default: the bundled model)
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

from _common import pin_to_cores
from edge_sets import training_edges

from vgm_studio.model.registry import BUNDLED_MODEL

DEFAULT = BUNDLED_MODEL
KEYS = ("tp", "fp", "tn", "fn")


def _state_hash(state) -> str:
    h = hashlib.sha256()
    for name in sorted(state or {}):
        h.update(name.encode())
        h.update(state[name].detach().cpu().numpy().tobytes())
    return h.hexdigest()


def _files(recorded: list[dict]) -> list[Path]:
    by_name = {p.name: p for p in training_edges()}
    return [
        Path(r["path"]) if Path(r["path"]).exists() else by_name[Path(r["path"]).name]
        for r in recorded
    ]


def validation_rows(path: Path, checkpoint, data):
    """The validation split of ``data`` the checkpoint at ``path`` was judged on, made again:
    its labels, the checkpoint's p(success) there and the calibration rule's real rows."""
    from vgm_studio.model.calibration import calibration_mask
    from vgm_studio.model.training import stratified_split
    from vgm_studio.model.validator import Validator

    config = checkpoint.training["config"]
    _, val = stratified_split(data.labels, data.groups, config["val_fraction"], config["seed"])
    labels = data.labels[val]
    counts = {"success": int(labels.sum()), "failure": int((~labels).sum())}
    if counts != checkpoint.training["counts"]["validation"]:
        raise SystemExit(f"{path}: validation split not reproduced ({counts}); left as it was")
    probs = Validator.load(path, device="cpu").predict_samples([data.samples[i] for i in val])
    return labels, probs, calibration_mask([data.edges[i] for i in val], labels)


def recalibrate(path: Path, data=None) -> str:
    """Applies the calibration rule to the checkpoint at ``path``; returns a report line.

    ``data``: the labelled set it was trained on, when the caller has it read already.
    """
    import numpy as np

    from vgm_studio.model.calibration import calibrate
    from vgm_studio.model.checkpoint import load_checkpoint, save_checkpoint
    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.training import read_labelled

    checkpoint = load_checkpoint(path)
    before = _state_hash(checkpoint.state_dict)
    if data is None:
        data = read_labelled(_files(checkpoint.training["files"]), progress=False)
    labels, probs, real = validation_rows(path, checkpoint, data)
    # Checkpoints from before the rule were judged on every validation edge.
    was = real if "calibration_edges" in checkpoint.training else np.ones_like(real)
    again = binary_metrics(labels[was], probs[was], checkpoint.threshold)
    if any(again[k] != checkpoint.metrics[k] for k in KEYS):
        raise SystemExit(f"{path}: recorded validation figures not reproduced; left as it was")
    old = checkpoint.threshold
    calibrate(checkpoint, labels, probs, real)
    checkpoint.training["calibration_edges"] = int(real.sum())
    save_checkpoint(path, checkpoint)
    assert _state_hash(load_checkpoint(path).state_dict) == before, "weights changed"
    return (
        f"{path.name}: split of {len(labels)} reproduced; cut {old:.2f} → "
        f"{checkpoint.threshold:.2f} chosen on {int(real.sum())} real logs' edges; weights "
        f"unchanged ({before[:12]})"
    )


def main() -> None:
    pin_to_cores(2)
    for path in [Path(a) for a in sys.argv[1:]] or [DEFAULT]:
        print(recalibrate(path), flush=True)


if __name__ == "__main__":
    sys.exit(main())
