"""Adds the validation precision curve to the bundled vgmnet-default.pt, without retraining.

The bundled checkpoint was written before checkpoints kept a curve. Its validation split is
reproducible: the training files it records (same content hashes; the simulated worlds' edge
files differ only in the folder they name) and ``stratified_split`` with its recorded
fraction and seed give the same 4,133 pairs. The script checks that its recorded validation
confusion counts come out again, computes the curve, and writes it in, leaving the weights
bit for bit as they were (a hash of the state dict before and after).

Run: python benchmarks/default_curve.py
"""

from __future__ import annotations

import hashlib
import sys

from _common import REPO, pin_to_cores
from edge_sets import training_edges

DEFAULT = REPO / "assets" / "models" / "vgmnet-default.pt"


def _state_hash(state) -> str:
    h = hashlib.sha256()
    for name in sorted(state):
        h.update(name.encode())
        h.update(state[name].detach().cpu().numpy().tobytes())
    return h.hexdigest()


def main() -> None:
    pin_to_cores(2)
    from vgm_studio.core.hashing import content_hash
    from vgm_studio.model.checkpoint import load_checkpoint, save_checkpoint
    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.operating import precision_curve
    from vgm_studio.model.training import read_labelled, stratified_split
    from vgm_studio.model.validator import Validator

    checkpoint = load_checkpoint(DEFAULT)
    before = _state_hash(checkpoint.state_dict)
    files = {p.name: p for p in training_edges()}
    recorded = checkpoint.training["files"]
    paths = [files[r["path"].rsplit("/", 1)[-1]] for r in recorded]
    for r, p in zip(recorded, paths, strict=True):
        note = "same" if content_hash(p) == r["sha256"] else "differs (folder names only?)"
        print(f"{p.name}: {note}")
    data = read_labelled(paths, progress=False)
    config = checkpoint.training["config"]
    _, val = stratified_split(data.labels, data.groups, config["val_fraction"], config["seed"])
    probs = Validator.load(DEFAULT, device="cpu").predict_samples([data.samples[i] for i in val])
    labels = data.labels[val]
    again = binary_metrics(labels, probs, checkpoint.threshold)
    keys = ("tp", "fp", "tn", "fn")
    if any(again[k] != checkpoint.metrics[k] for k in keys):
        raise SystemExit(
            f"validation split not reproduced: {[again[k] for k in keys]} against the "
            f"recorded {[checkpoint.metrics[k] for k in keys]}; curve not written"
        )
    checkpoint.curve = precision_curve(labels, probs)
    save_checkpoint(DEFAULT, checkpoint)
    after = _state_hash(load_checkpoint(DEFAULT).state_dict)
    assert after == before, "weights changed"
    print(
        f"validation split reproduced ({len(val)} pairs, TP/FP/TN/FN "
        f"{'/'.join(str(again[k]) for k in keys)} as recorded); curve of "
        f"{len(checkpoint.curve.thresholds)} cuts written; state dict sha256 {before[:16]} "
        "before and after"
    )


if __name__ == "__main__":
    sys.exit(main())
