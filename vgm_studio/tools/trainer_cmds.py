"""``vgm-studio trainer`` and ``vgm-studio models``: the background trainer and its versions."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.errors import InputError
from vgm_studio.tools.options import MinHeldOutOpt, ModelsDirOpt, StoreOpt, store_location

WorkspaceOrStoreOpt = Annotated[
    Path | None, typer.Option(metavar="DIR", help="Workspace folder (or --store URL).")
]


def trainer(
    workspace: WorkspaceOrStoreOpt = None,
    store: StoreOpt = None,
    models_dir: ModelsDirOpt = None,
    retrain_every: Annotated[
        int, typer.Option(min=1, help="Train after this many new labels.")
    ] = 25,
    base: Annotated[
        list[Path] | None,
        typer.Option(metavar="EDGES.jsonl", help="Labelled edges to train on too (repeatable)."),
    ] = None,
    from_scratch: Annotated[
        bool, typer.Option(help="Start every version from fresh weights, not the active one.")
    ] = False,
    epochs: Annotated[int, typer.Option(min=1, help="Epochs at most per version.")] = 12,
    epoch_size: Annotated[int, typer.Option(min=1, help="Class-balanced draws per epoch.")] = 1024,
    min_held_out: MinHeldOutOpt = 20,
) -> None:
    """Train model versions from a workspace's labels as they come in (runs until Ctrl-C)."""
    from vgm_studio.trainer.fit import FitConfig
    from vgm_studio.trainer.process import run_trainer
    from vgm_studio.trainer.promotion import PromotionRule
    from vgm_studio.trainer.worker import TrainerConfig

    config = TrainerConfig(
        retrain_every=retrain_every,
        base=tuple(base or ()),
        from_scratch=from_scratch,
        fit=FitConfig(epochs=epochs, epoch_size=epoch_size),
        promotion=PromotionRule(min_per_class=min_held_out),
    )
    folder, url = store_location(workspace, store, models_dir)
    run_trainer(folder, config, url=url)


def models(
    workspace: WorkspaceOrStoreOpt = None,
    store: StoreOpt = None,
    models_dir: ModelsDirOpt = None,
    export: Annotated[
        int | None, typer.Option(metavar="N", min=1, help="Write version vN out as a checkpoint.")
    ] = None,
    out: Annotated[
        Path | None, typer.Option(metavar="FILE.pt", help="Where --export writes.")
    ] = None,
) -> None:
    """List a workspace's model versions and their held-out figures, or export one."""
    from vgm_studio.services.models import export_version, list_versions

    folder, url = store_location(workspace, store, models_dir)
    if export is None and out is None:
        typer.echo(list_versions(folder, url))
    elif export is not None and out is not None:
        typer.echo(export_version(folder, export, out, url))
    else:
        raise InputError(None, "--export N and --out FILE.pt go together")
