"""``vgm-studio train`` and ``vgm-studio eval``: models from labelled edges, and their figures."""

from __future__ import annotations

import json
import time
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer

from vgm_studio.errors import InputError

EdgesArg = Annotated[
    list[Path], typer.Argument(metavar="EDGES.jsonl...", help="Labelled edge files.")
]


class ModelName(str, Enum):
    vgmnet = "vgmnet"
    vgmnet_paper = "vgmnet-paper"
    rgb_baseline = "rgb-baseline"
    score = "score"


class Device(str, Enum):
    auto = "auto"
    cpu = "cpu"
    cuda = "cuda"


def train(
    edges: EdgesArg,
    out: Annotated[Path, typer.Option(help="Checkpoint to write (.pt).")],
    model: Annotated[ModelName, typer.Option(help="Which model.")] = ModelName.vgmnet,
    epochs: Annotated[int, typer.Option(min=1, help="Epochs at most.")] = 12,
    batch_size: Annotated[int, typer.Option(min=1, help="Pairs per step.")] = 64,
    lr: Annotated[float, typer.Option(min=0.0, help="Adam learning rate.")] = 2e-3,
    patience: Annotated[int, typer.Option(min=1, help="Early-stopping patience.")] = 4,
    val_fraction: Annotated[
        float, typer.Option(min=0.0, max=0.9, help="Held out per (log, label).")
    ] = 0.15,
    epoch_size: Annotated[int, typer.Option(min=1, help="Class-balanced draws per epoch.")] = 6000,
    max_train: Annotated[
        int | None, typer.Option(min=2, help="Train on at most this many edges.")
    ] = None,
    augment: Annotated[bool, typer.Option(help="Random rigid rotations of pairs.")] = True,
    figures: Annotated[
        bool, typer.Option(help="vgmnet: also read the matcher's inlier ratio and residual.")
    ] = True,
    occupancy: Annotated[
        bool, typer.Option(help="vgmnet: also read each scan's occupied cells, as a plot does.")
    ] = False,
    spread: Annotated[
        bool | None,
        typer.Option(
            help="vgmnet, score: also read the match's position and heading variances.",
            show_default="on for vgmnet, off for score",
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed for split, draws and weights.")] = 0,
    device: Annotated[Device, typer.Option(help="auto takes a GPU when there is one.")] = (
        Device.auto
    ),
    threads: Annotated[int | None, typer.Option(min=1, help="torch CPU threads.")] = None,
) -> None:
    """Train a validator on labelled edges (ambiguous and unlabelled ones are left out)."""
    from vgm_studio.model.training import TrainConfig, read_labelled
    from vgm_studio.model.training import train as run

    if out.suffix != ".pt":
        raise typer.BadParameter("the checkpoint must end in .pt", param_hint="--out")
    data = read_labelled(edges)
    hyper: dict[str, Any] = {}
    if model is ModelName.vgmnet:
        hyper = {
            "figures": figures,
            "occupancy": occupancy,
            "spread": figures and spread is not False,
        }
    elif model is ModelName.score:
        hyper = {"spread": bool(spread)}
    config = TrainConfig(
        model=model.value,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        patience=patience,
        val_fraction=val_fraction,
        epoch_size=epoch_size,
        max_train=max_train,
        augment=augment,
        seed=seed,
        device=device.value,
        threads=threads,
        hyper=hyper,
    )
    try:
        payload = run(data, config, out, log=lambda line: typer.echo(line, err=True))
    except ValueError as exc:
        raise InputError(out, str(exc)) from None
    m = {"accuracy": float("nan"), "f1": float("nan"), "auc": float("nan"), **payload["metrics"]}
    typer.echo(
        f"wrote {out} ({payload['training']['seconds']:.0f} s); validation: "
        f"accuracy {m['accuracy']:.3f}, F1 {m['f1']:.3f}, AUC {m['auc']:.3f} "
        f"at p(success) ≥ {payload['threshold']:.2f}"
    )


def evaluate(
    model: Annotated[Path, typer.Argument(metavar="MODEL.pt", help="A trained checkpoint.")],
    edges: EdgesArg,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Also write the figures as JSON here.")
    ] = None,
    device: Annotated[Device, typer.Option(help="auto takes a GPU when there is one.")] = (
        Device.auto
    ),
    batch_size: Annotated[int, typer.Option(min=1, help="Pairs per batch.")] = 64,
) -> None:
    """Evaluate a model on labelled edges: accuracy, precision, recall, F1, AUC, TP/FP/TN/FN."""
    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.training import read_labelled
    from vgm_studio.model.validator import Validator

    validator = Validator.load(model, device=device.value)
    data = read_labelled(edges)
    start = time.perf_counter()
    probs = validator.predict_samples(data.samples, batch_size)
    seconds = time.perf_counter() - start
    m = binary_metrics(data.labels, probs, validator.threshold)
    typer.echo(format_metrics(validator.name, m, validator.threshold, seconds))
    if json_out is not None:
        record = {
            **m,
            "model": validator.name,
            "threshold": validator.threshold,
            "seconds": seconds,
            "edges": [str(p) for p in edges],
        }
        try:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(record, indent=2) + "\n")
        except OSError as exc:
            raise InputError(
                json_out, f"cannot write ({exc.strerror or type(exc).__name__})"
            ) from None


def format_metrics(name: str, m: dict[str, Any], threshold: float, seconds: float) -> str:
    """The paper's table layout: the rates, then the confusion counts."""
    rows = [
        f"model      {name}  (success = positive, p(success) ≥ {threshold:.2f})",
        f"edges      {m['n']}  ({m['tp'] + m['fn']} success, {m['tn'] + m['fp']} failure)",
        f"accuracy   {m['accuracy']:.4f}",
        f"precision  {m['precision']:.4f}",
        f"recall     {m['recall']:.4f}",
        f"F1         {m['f1']:.4f}",
        f"ROC AUC    {m['auc']:.4f}",
        "",
        "                 predicted success  predicted failure",
        f"true success     TP {m['tp']:>14}  FN {m['fn']:>14}",
        f"true failure     FP {m['fp']:>14}  TN {m['tn']:>14}",
        "",
        f"inference  {seconds:.2f} s ({m['n'] / max(seconds, 1e-9):.0f} pairs/s, VGMs included)",
    ]
    return "\n".join(rows)
