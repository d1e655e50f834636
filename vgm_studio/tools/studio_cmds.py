"""``vgm-studio label``, ``demo``, ``export`` and ``import``: the labeling studio's commands."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.datasets import ReadOptions
from vgm_studio.tools.options import (
    AnnotatorOpt,
    HostOpt,
    MaxLoopsOpt,
    MinHeldOutOpt,
    ModelsDirOpt,
    NoTrainerOpt,
    PortOpt,
    RetrainOpt,
    StoreOpt,
    store_location,
    with_read_options,
)

DemoWorkspaceOpt = Annotated[
    Path | None, typer.Option(metavar="DIR", help="Workspace folder.", show_default="vgm-demo")
]
WorkspaceOrStoreOpt = Annotated[
    Path | None, typer.Option(metavar="DIR", help="Workspace folder (or --store URL).")
]


def _warn(line: str) -> None:
    typer.echo(line, err=True)


@with_read_options
def label(
    source: Annotated[
        Path,
        typer.Argument(metavar="SOURCE", help="A log (CARMEN, ROS bag) or an EDGES.jsonl file."),
    ],
    read: ReadOptions,
    reference: Annotated[
        Path | None,
        typer.Option(metavar="REF", help="Reference for a log: corrected log or relations."),
    ] = None,
    workspace: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR", help="Workspace folder (label store).", show_default="SOURCE-name.studio"
        ),
    ] = None,
    store: StoreOpt = None,
    models_dir: ModelsDirOpt = None,
    port: PortOpt = 8080,
    host: HostOpt = "127.0.0.1",
    annotator: AnnotatorOpt = None,
    model: Annotated[
        Path | None,
        typer.Option(
            metavar="MODEL.pt",
            help="Model whose p(success) is shown.",
            show_default="the bundled vgmnet-default.pt",
        ),
    ] = None,
    no_model: Annotated[bool, typer.Option("--no-model", help="Show no model predictions.")] = (
        False
    ),
    no_trainer: NoTrainerOpt = False,
    retrain_every: RetrainOpt = 25,
    min_held_out: MinHeldOutOpt = 20,
    base: Annotated[
        list[Path] | None,
        typer.Option("--base", metavar="EDGES.jsonl", help="Labelled edges the trainer also uses."),
    ] = None,
    max_loops: MaxLoopsOpt = 2000,
    time_offset: Annotated[
        float, typer.Option(help="Seconds added to a reference log's timestamps.")
    ] = 0.0,
) -> None:
    """Serve a log's candidate edges (or an edges file) in the browser for labeling."""
    from vgm_studio.labels.opening import open_store
    from vgm_studio.studio.app import StudioConfig, check_port_free, default_annotator
    from vgm_studio.studio.serve import TrainerOptions, serve
    from vgm_studio.workspace import choose_model, fill_workspace

    start = time.perf_counter()
    folder, url = store_location(workspace, store, models_dir, Path(f"{source.stem}.studio"))
    check_port_free(host, port)
    opened = open_store(folder, url)
    fill_workspace(
        opened, source, reference, read, max_loops, time_offset, say=typer.echo, warn=_warn
    )
    serve(
        opened,
        StudioConfig(host=host, port=port, annotator=annotator or default_annotator()),
        model=choose_model(model, no_model, warn=_warn),
        trainer=None if no_trainer else TrainerOptions.checked(retrain_every, base, min_held_out),
        ready_seconds=time.perf_counter() - start,
    )


def demo(
    workspace: DemoWorkspaceOpt = None,
    store: StoreOpt = None,
    models_dir: ModelsDirOpt = None,
    port: PortOpt = 8080,
    host: HostOpt = "127.0.0.1",
    annotator: AnnotatorOpt = None,
    serve_app: Annotated[
        bool, typer.Option("--serve/--no-serve", help="Serve the studio (else prepare and exit).")
    ] = True,
    no_trainer: NoTrainerOpt = False,
    retrain_every: RetrainOpt = 25,
) -> None:
    """Label the bundled demo log in the browser, with the bundled model's predictions."""
    from vgm_studio.studio.app import StudioConfig, check_port_free, default_annotator
    from vgm_studio.studio.serve import TrainerOptions, serve
    from vgm_studio.workspace import open_demo

    start = time.perf_counter()
    folder, url = store_location(workspace, store, models_dir, Path("vgm-demo"))
    if serve_app:
        check_port_free(host, port)
    opened, model = open_demo(folder, url, predict=not serve_app, say=typer.echo, warn=_warn)
    if not serve_app:
        seconds = time.perf_counter() - start
        where = url or f"workspace {folder}"
        typer.echo(f"{where} ready: {opened.count_edges()} edges ({seconds:.1f} s)")
        opened.close()
        return
    serve(
        opened,
        StudioConfig(host=host, port=port, annotator=annotator or default_annotator()),
        model=model,
        trainer=None if no_trainer else TrainerOptions.checked(retrain_every, None),
        ready_seconds=time.perf_counter() - start,
    )


def export(
    out: Annotated[Path, typer.Option(metavar="FILE", help="Labels file: .jsonl or .csv.")],
    workspace: WorkspaceOrStoreOpt = None,
    store: StoreOpt = None,
) -> None:
    """Write a workspace's (or team store's) labels as JSONL (a training file) or CSV."""
    from vgm_studio.labels.opening import open_store
    from vgm_studio.labels.transfer import export_labels

    folder, url = store_location(workspace, store, None)
    count = export_labels(open_store(folder, url, create=False), out)
    typer.echo(f"wrote {count} labels to {out}")


def import_(
    files: Annotated[list[Path], typer.Argument(metavar="FILE...", help="Exported label files.")],
    workspace: WorkspaceOrStoreOpt = None,
    store: StoreOpt = None,
) -> None:
    """Add exported labels (.jsonl or .csv) to a workspace or team store; the newer label wins."""
    from vgm_studio.labels.opening import open_store
    from vgm_studio.labels.transfer import import_labels

    folder, url = store_location(workspace, store, None)
    opened = open_store(folder, url)
    for path in files:
        edges, labels = import_labels(opened, path)
        typer.echo(f"{path}: {labels} labels added or updated, {edges} new edges")
