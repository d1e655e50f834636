"""``vgm-studio train`` and ``vgm-studio eval``: models from labelled edges, and their figures."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.model.registry import MODEL_NAMES, HyperFlags, entry
from vgm_studio.tools.options import Device, DeviceOpt, one_of, writable_file

EdgesArg = Annotated[
    list[Path], typer.Argument(metavar="EDGES.jsonl...", help="Labelled edge files.")
]


def train(
    edges: EdgesArg,
    out: Annotated[Path, typer.Option(help="Checkpoint to write (.pt).")],
    model: Annotated[str, one_of(MODEL_NAMES, "Which model.")] = "vgmnet",
    epochs: Annotated[int, typer.Option(min=1, help="Epochs at most.")] = 30,
    batch_size: Annotated[int, typer.Option(min=1, help="Pairs per step.")] = 64,
    lr: Annotated[float, typer.Option(min=0.0, help="Adam learning rate.")] = 2e-3,
    patience: Annotated[int, typer.Option(min=1, help="Early-stopping patience.")] = 8,
    val_fraction: Annotated[
        float, typer.Option(min=0.0, max=0.9, help="Held out per (log, label).")
    ] = 0.15,
    epoch_size: Annotated[int, typer.Option(min=1, help="Class-balanced draws per epoch.")] = 6000,
    max_train: Annotated[
        int | None, typer.Option(min=2, help="Train on at most this many edges.")
    ] = None,
    augment: Annotated[bool, typer.Option(help="Random rigid rotations of pairs.")] = True,
    occlude: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help="Share of training draws that lose one scan's points in a random sector "
            "(60-180°), so pairs that share little are seen in training.",
        ),
    ] = 0.0,
    # The defaults are HyperFlags's: the bundled model's inputs (``default_hyper``).
    figures: Annotated[
        bool, typer.Option(help="vgmnet: also read the matcher's figures (--inliers, --spread).")
    ] = HyperFlags.figures,
    occupancy: Annotated[
        bool, typer.Option(help="vgmnet: also read each scan's occupied cells, as a plot does.")
    ] = HyperFlags.occupancy,
    spread: Annotated[
        bool | None,
        typer.Option(
            help="vgmnet, score: also read the match's position and heading variances.",
            show_default="on for vgmnet, off for score",
        ),
    ] = None,
    inliers: Annotated[
        bool,
        typer.Option(
            help="vgmnet: the figures include the matcher's inlier ratio and residual "
            "(--no-inliers: the variances alone)."
        ),
    ] = HyperFlags.inliers,
    blind_head: Annotated[
        bool | None,
        typer.Option(
            help="vgmnet: a second head that judges without the figures; the logit is the "
            "mean of the two.",
            show_default="on with the figures",
        ),
    ] = None,
    cell_size: Annotated[
        float,
        typer.Option(
            min=0.01,
            max=1.0,
            help="vgmnet, vgmnet-paper: VGM cell edge in metres; the 400 cells span 400× it "
            "(0.05: the paper's 20 m; 0.1: 40 m, which keeps a campus scan's far points).",
        ),
    ] = 0.05,
    context: Annotated[
        int | None,
        typer.Option(
            min=0,
            max=16,
            show_default=False,
            help="Draw each side of a pair from its scan and up to this many neighbour scans "
            "a side in the log, each matched to the scan (0: the scan alone). eval, predict "
            "and slam read edges the same way. Unset: the bundled model's for vgmnet (the "
            "background trainer's too), 0 for the others.",
        ),
    ] = None,
    covisible: Annotated[
        bool | None,
        typer.Option(
            show_default=False,
            help="With --context: keep a neighbour's points only where the pair's other scan "
            "saw (its field of view, out to each beam's range + 0.3 m). Unset: as the bundled "
            "model where it has neighbours.",
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed for split, draws and weights.")] = 0,
    bn_batches: Annotated[
        int,
        typer.Option(
            min=0, help="Recompute batch norm's statistics over this many batches per epoch."
        ),
    ] = 0,
    device: DeviceOpt = Device.auto,
    threads: Annotated[int | None, typer.Option(min=1, help="torch CPU threads.")] = None,
    init: Annotated[
        Path | None,
        typer.Option(metavar="MODEL.pt", help="Start from this checkpoint's weights (same model)."),
    ] = None,
) -> None:
    """Train a validator on labelled edges (ambiguous and unlabelled ones are left out).

    Needs at least 10 edges labelled success and 10 labelled failure: a share of each class
    (--val-fraction) is held out, and early stopping, the p(success) cut and the figures are
    read there.
    """
    from vgm_studio.model.context import DEFAULT_CONTEXT, Context
    from vgm_studio.model.training import TrainConfig
    from vgm_studio.services.models import train_model
    from vgm_studio.vgm.grid import VGMParams

    if out.suffix != ".pt":
        raise typer.BadParameter("the checkpoint must end in .pt", param_hint="--out")
    # Unasked, vgmnet is drawn as the bundled model is; the other models read single scans.
    bundled = DEFAULT_CONTEXT if model == "vgmnet" else Context()
    neighbours = bundled.neighbours if context is None else context
    if covisible and not neighbours:
        raise typer.BadParameter(
            "crops neighbours, so it needs --context N", param_hint="--covisible"
        )
    crop = (bundled.covisible if covisible is None else covisible) and neighbours > 0
    if figures and not inliers and spread is False:
        raise typer.BadParameter(
            "with --no-spread too it leaves no figures to read; use --no-figures",
            param_hint="--no-inliers",
        )
    # Unasked, the bundled model's choice (``HyperFlags.blind``), which --no-figures drops.
    blind = HyperFlags.blind if blind_head is None else blind_head
    if blind_head is True and not figures:
        raise typer.BadParameter(
            "is a second head beside the one that reads the figures; drop --no-figures",
            param_hint="--blind-head",
        )
    config = TrainConfig(
        model=model,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        patience=patience,
        val_fraction=val_fraction,
        epoch_size=epoch_size,
        max_train=max_train,
        augment=augment,
        occlude=occlude,
        seed=seed,
        bn_batches=bn_batches,
        device=device.value,
        threads=threads,
        init=None if init is None else str(init),
        hyper=entry(model).hyper(HyperFlags(figures, occupancy, spread, inliers, blind)),
        vgm=VGMParams(resolution=cell_size),
        context=Context(neighbours=neighbours, covisible=crop),
    )
    typer.echo(train_model(edges, out, config, warn=lambda line: typer.echo(line, err=True)))


def evaluate(
    model: Annotated[Path, typer.Argument(metavar="MODEL.pt", help="A trained checkpoint.")],
    edges: EdgesArg,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Also write the figures as JSON here.")
    ] = None,
    device: DeviceOpt = Device.auto,
    batch_size: Annotated[int, typer.Option(min=1, help="Pairs per batch.")] = 64,
) -> None:
    """Evaluate a model on labelled edges: accuracy, precision, recall, F1, AUC, TP/FP/TN/FN."""
    from vgm_studio.services.models import evaluate_model

    if json_out is not None:
        writable_file(json_out)  # before the edges' scans are read: the refusal comes alone
    typer.echo(evaluate_model(model, edges, json_out, device.value, batch_size))
