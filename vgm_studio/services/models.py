"""``vgm-studio train``, ``eval`` and ``models``: validators trained, judged, listed, exported."""

from __future__ import annotations

import math
import shutil
import time
from pathlib import Path
from typing import Any

from vgm_studio.atomic import atomic_path, write_json_atomically
from vgm_studio.errors import InputError
from vgm_studio.labels.opening import open_store
from vgm_studio.model.checkpoint import Checkpoint, load_checkpoint
from vgm_studio.model.metrics import binary_metrics
from vgm_studio.model.training import TrainConfig, read_labelled, train
from vgm_studio.model.validator import Validator
from vgm_studio.services import Say, quiet
from vgm_studio.trainer.registry import ModelRecord, list_models


def train_model(edges: list[Path], out: Path, config: TrainConfig, warn: Say = quiet) -> str:
    """Trains a validator on labelled edge files and writes its checkpoint.

    Returns:
        A line: where it went, how long it took, its validation figures.

    Raises:
        InputError: No labelled edges, or training cannot start.
    """
    data = read_labelled(edges, context=config.context, to_train=True)
    try:
        checkpoint = train(data, config, out, log=warn)
    except ValueError as exc:
        raise InputError(out, str(exc)) from None
    return trained_line(out, checkpoint)


def trained_line(out: Path, checkpoint: Checkpoint) -> str:
    """One line on a checkpoint just written; a figure its validation split cannot give is
    "n/a", with the reason."""
    held = checkpoint.training.get("counts", {}).get("validation", {})
    cut = f"at p(success) ≥ {checkpoint.threshold:.2f}"
    m = checkpoint.metrics
    if not m:
        # Nothing held out (--val-fraction 0, or each log too few of a class to spare one).
        figures = "n/a (no edge was held out for validation; raise --val-fraction)"
        cut = f"at the default p(success) ≥ {checkpoint.threshold:.2f}"
    else:
        figures = (
            f"accuracy {shown(m.get('accuracy'))}, F1 {shown(m.get('f1'))}, "
            f"AUC {shown(m.get('auc'))}"
        )
        missing = [c for c in ("success", "failure") if held and not held.get(c)]
        if missing:
            figures += f" (n/a: the validation split holds no {missing[0]} edge)"
    return f"wrote {out} ({checkpoint.training['seconds']:.0f} s); validation: {figures} {cut}"


def shown(value: Any, digits: int = 3) -> str:
    """A figure as printed: ``n/a`` where it is missing or not a finite number, never nan."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return "n/a"
    return f"{value:.{digits}f}"


def finite_or_none(doc: dict[str, Any]) -> dict[str, Any]:
    """``doc`` with NaN and ±inf as None: JSON has no NaN, and a reader should see no figure."""
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in doc.items()}


def evaluate_model(
    model: Path,
    edges: list[Path],
    json_out: Path | None = None,
    device: str = "auto",
    batch_size: int = 64,
) -> str:
    """A model's figures on labelled edges, as the paper's table; also as JSON when asked."""
    validator = Validator.load(model, device=device)
    data = read_labelled(edges, context=validator.context)
    start = time.perf_counter()
    probs = validator.predict_samples(data.samples, batch_size)
    seconds = time.perf_counter() - start
    m = binary_metrics(data.labels, probs, validator.threshold)
    if json_out is not None:
        record = {
            **finite_or_none(m),
            "model": validator.name,
            "threshold": validator.threshold,
            "seconds": seconds,
            "edges": [str(p) for p in edges],
        }
        try:
            write_json_atomically(json_out, record)
        except OSError as exc:
            raise InputError(
                json_out, f"cannot write ({exc.strerror or type(exc).__name__})"
            ) from None
    return format_metrics(validator.name, m, validator.threshold, seconds)


def format_metrics(name: str, m: dict[str, Any], threshold: float, seconds: float) -> str:
    """The paper's table layout: the rates, then the confusion counts; "n/a" and why for a
    figure these edges cannot give."""
    success, failure = m["tp"] + m["fn"], m["tn"] + m["fp"]
    auc = shown(m["auc"], 4)
    if auc == "n/a":
        only = "success" if success else "failure"
        auc += f" (needs both classes; these edges are all {only})"
    rows = [
        f"model      {name}  (success = positive, p(success) ≥ {threshold:.2f})",
        f"edges      {m['n']}  ({success} success, {failure} failure)",
        f"accuracy   {shown(m['accuracy'], 4)}",
        f"precision  {shown(m['precision'], 4)}",
        f"recall     {shown(m['recall'], 4)}",
        f"F1         {shown(m['f1'], 4)}",
        f"ROC AUC    {auc}",
        "",
        "                 predicted success  predicted failure",
        f"true success     TP {m['tp']:>14}  FN {m['fn']:>14}",
        f"true failure     FP {m['fp']:>14}  TN {m['tn']:>14}",
        "",
        f"inference  {seconds:.2f} s ({m['n'] / max(seconds, 1e-9):.0f} pairs/s, VGMs included)",
    ]
    return "\n".join(rows)


def _figure(metrics: dict[str, Any], key: str) -> str:
    value = metrics.get(key)
    if not isinstance(value, int | float) or not math.isfinite(value):
        return "–"
    return f"{value:.3f}"


def models_table(records: list[ModelRecord]) -> str:
    """The versions as a Markdown-like table: held-out figures, labels, time, promotion."""
    header = ["version", "created (UTC)", "labels", "held out", "accuracy", "F1", "AUC", "cut"]
    header += ["seconds", "status", "why"]
    rows = []
    for m in records:
        held = m.metrics.get("counts", {}).get("held_out", {})
        status = "active" if m.active else ("promoted" if m.promoted else "not promoted")
        rows.append(
            [
                m.name,
                m.created_at[:19].replace("T", " "),
                str(m.labels_seen),
                str(sum(held.values())) if held else "0",
                *(_figure(m.metrics, k) for k in ("accuracy", "f1", "auc", "threshold")),
                f"{m.seconds:.0f}",
                status,
                str(m.metrics.get("compared", {}).get("reason", "")),
            ]
        )
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = [
        "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
        for r in [header, *rows]
    ]
    return "\n".join(lines)


def list_versions(workspace: Path, url: str | None = None) -> str:
    """A workspace's (or team store's) versions as a table, or a line saying there are none."""
    store = open_store(workspace, url, create=False)
    try:
        records = list_models(store)
    finally:
        store.close()
    if not records:
        return f"{url or workspace}: no model versions yet (run vgm-studio trainer)"
    return models_table(records)


def export_version(workspace: Path, version: int, out: Path, url: str | None = None) -> str:
    """Writes version ``vN`` out as a checkpoint file.

    Raises:
        InputError: No such version, a damaged file, or ``out`` cannot be written.
    """
    if out.suffix != ".pt":
        raise InputError(out, "the checkpoint must end in .pt")
    store = open_store(workspace, url, create=False)
    try:
        records = list_models(store)
    finally:
        store.close()
    record = next((m for m in records if m.version == version), None)
    if record is None:
        known = ", ".join(m.name for m in records) or "none"
        raise InputError(workspace, f"no version v{version} (versions: {known})")
    load_checkpoint(record.path)  # refuses a damaged file rather than copying it
    _copy_atomically(record.path, out)
    return f"wrote v{version} to {out}"


def _copy_atomically(source: Path, out: Path) -> None:
    """Copies to a temporary file beside ``out``, then renames: ``out`` is whole or untouched."""
    if out.is_dir():
        raise InputError(out, "is a folder; give a file name to write")
    try:
        with atomic_path(out) as tmp:
            shutil.copyfile(source, tmp)
    except OSError as exc:
        raise InputError(out, f"cannot write here ({exc.strerror or exc})") from None
