"""``vgm-studio label``, ``demo``, ``export`` and ``import``: the labeling studio's commands."""

from __future__ import annotations

import errno
import socket
import time
from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.datasets import ReadOptions
from vgm_studio.datasets.source import JoinOptions
from vgm_studio.errors import InputError
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
    TimeToleranceOpt,
    TokenOpt,
    WorkspaceOpt,
    number,
    process_start,
    store_location,
    with_read_options,
)

DemoWorkspaceOpt = Annotated[
    Path | None, typer.Option(metavar="DIR", help="Workspace folder.", show_default="vgm-demo")
]
WorkspaceOrStoreOpt = Annotated[
    Path | None, typer.Option(metavar="DIR", help="Workspace folder (or --store URL).")
]
LoopPrecisionOpt = Annotated[
    float,
    typer.Option(
        help="Cut the model's calls (what it says, the model-disagrees queue) where its "
        "validation precision reaches this, in [0, 1] (0: the checkpoint's threshold).",
        callback=number(0, 1),
    ),
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
    token: TokenOpt = None,
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
    loop_precision: LoopPrecisionOpt = 0.0,
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
    time_tolerance: TimeToleranceOpt = 0.05,
) -> None:
    """Serve a log's candidate edges (or an edges file) in the browser for labeling."""
    from vgm_studio.studio.config import check_port_free

    folder, url = store_location(workspace, store, models_dir, Path(f"{source.stem}.studio"))
    check_host(host)
    # Before torch, viser and the store load (seconds): a port in use is said at once.
    check_port_free(host, port)
    from vgm_studio.labels.opening import store_to_fill
    from vgm_studio.studio.app import StudioConfig, default_annotator
    from vgm_studio.studio.serve import TrainerOptions, added_text, serve
    from vgm_studio.workspace import check_source, choose_model, fill_workspace

    # Every cheap check before the workspace is made, and the making of candidate edges
    # (minutes on a large log): a typo costs neither a stray folder nor the wait.
    check_source(source, reference)
    chosen = choose_model(model, no_model, precision=loop_precision or None, warn=_warn)
    trainer = None if no_trainer else TrainerOptions.checked(retrain_every, base, min_held_out)
    with store_to_fill(folder, url) as opened:
        before = opened.count_edges()
        added = fill_workspace(
            opened,
            source,
            reference,
            read,
            max_loops,
            JoinOptions(time_tolerance=time_tolerance, time_offset=time_offset),
            say=typer.echo,
            warn=_warn,
        )
    if before:  # an existing workspace: say what this source changed in it
        typer.echo(added_text(opened, source, before, added))
    serve(
        opened,
        StudioConfig(host=host, port=port, annotator=annotator or default_annotator(), token=token),
        model=chosen,
        precision=loop_precision or None,
        trainer=trainer,
        started=process_start(),
    )


def check_host(host: str) -> None:
    """Refuses a ``--host`` that is not a name or address of this machine, in those words.

    Raises:
        InputError: The name does not resolve, or no interface of this machine has it.
    """
    try:
        family, kind, _, _, address = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)[0]
    except (socket.gaierror, UnicodeError):
        raise InputError(f"--host {host}", "is not a name or address that resolves") from None
    with socket.socket(family, kind) as probe:
        try:
            probe.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRNOTAVAIL:
                raise InputError(
                    f"--host {host}",
                    "is not an address of this machine; listen on 127.0.0.1 (this machine "
                    "only), 0.0.0.0 (every interface) or one of this machine's addresses",
                ) from None


def demo(
    workspace: DemoWorkspaceOpt = None,
    store: StoreOpt = None,
    models_dir: ModelsDirOpt = None,
    port: PortOpt = 8080,
    host: HostOpt = "127.0.0.1",
    token: TokenOpt = None,
    annotator: AnnotatorOpt = None,
    serve_app: Annotated[
        bool, typer.Option("--serve/--no-serve", help="Serve the studio (else prepare and exit).")
    ] = True,
    loop_precision: LoopPrecisionOpt = 0.0,
    no_trainer: NoTrainerOpt = False,
    retrain_every: RetrainOpt = 25,
) -> None:
    """Label the bundled demo log in the browser, with the bundled model's predictions."""
    from vgm_studio.studio.config import check_port_free

    start = time.perf_counter()
    folder, url = store_location(workspace, store, models_dir, Path("vgm-demo"))
    if serve_app:
        check_host(host)
        # Before torch, viser and the store load (seconds): a port in use is said at once.
        check_port_free(host, port)
    from vgm_studio.studio.app import StudioConfig, default_annotator
    from vgm_studio.studio.serve import TrainerOptions, serve
    from vgm_studio.workspace import open_demo

    precision = loop_precision or None
    opened, model = open_demo(
        folder, url, predict=not serve_app, precision=precision, say=typer.echo, warn=_warn
    )
    if not serve_app:
        seconds = time.perf_counter() - start
        where = url or f"workspace {folder}"
        typer.echo(f"{where} ready: {opened.count_edges()} edges ({seconds:.1f} s)")
        opened.close()
        return
    serve(
        opened,
        StudioConfig(host=host, port=port, annotator=annotator or default_annotator(), token=token),
        model=model,
        precision=precision,
        trainer=None if no_trainer else TrainerOptions.checked(retrain_every, None),
        started=process_start(),
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
    from vgm_studio.labels.opening import store_to_fill
    from vgm_studio.labels.transfer import read_label_file

    folder, url = store_location(workspace, store, None)
    # Every file is read and checked before the workspace is opened (or made): a bad row
    # leaves no store behind and changes none.
    read = [read_label_file(path) for path in files]
    with store_to_fill(folder, url) as opened:
        for labels_file in read:
            edges, labels = labels_file.write_to(opened)
            typer.echo(f"{labels_file.path}: {labels} labels added or updated, {edges} new edges")


def agreement(workspace: WorkspaceOpt) -> None:
    """Cohen's kappa and the shared edges of every pair of annotators in a workspace."""
    from vgm_studio.labels.agreement import agreement as pairs_of
    from vgm_studio.labels.agreement import agreement_lines
    from vgm_studio.labels.store import LabelStore

    store = LabelStore(workspace, create=False)
    pairs = pairs_of(store.label_map())
    store.close()
    if not pairs:
        typer.echo(f"{workspace}: no edge has labels of two annotators yet")
        return
    for line in agreement_lines(pairs):
        typer.echo(line)
