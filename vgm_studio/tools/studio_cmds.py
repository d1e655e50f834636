"""``vgm-studio label``, ``demo``, ``export`` and ``import``: the labeling studio's commands."""

from __future__ import annotations

import errno
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal, cast

import typer

from vgm_studio.datasets import ReadOptions
from vgm_studio.datasets.carmen import file_hash
from vgm_studio.errors import InputError, require_utf8_path
from vgm_studio.labels.store import LabelStore
from vgm_studio.studio.app import Studio, StudioConfig, check_port_free, default_annotator

PoseSource = Literal["auto", "odometry", "reference"]
REPO = Path(__file__).resolve().parents[2]
DEMO_LOG = REPO / "datasets" / "demo-seed0.log"
# Enough loop candidates to label for a while, few enough that the demo serves within seconds.
DEMO_LOOPS = 600
DEFAULT_MODEL = REPO / "assets" / "models" / "vgmnet-default.pt"
EXPOSED = (
    "viser has no authentication: anyone who can reach {host}:{port} can read and change "
    "these labels. Listen on 127.0.0.1 (the default) unless the network is trusted."
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


def _source_hash(source: Path) -> str:
    if source.is_file():
        return file_hash(source)
    # A ROS 2 bag is a folder: its files' hashes, in name order, stand for it.
    return "-".join(file_hash(p)[:16] for p in sorted(source.rglob("*")) if p.is_file())


def fill_workspace(
    store: LabelStore,
    source: Path,
    reference: Path | None,
    options: ReadOptions,
    max_loops: int = 2000,
    time_offset: float = 0.0,
) -> int:
    """Adds a log's candidate edges (made now, once per log) or an edges file to the store.

    Returns:
        How many edges were new.
    """
    from vgm_studio.matching.candidates import CandidateConfig, make_candidates
    from vgm_studio.matching.edge_scans import check_viewable
    from vgm_studio.matching.edges import read_edge_rows
    from vgm_studio.matching.matcher import ScanMatcher
    from vgm_studio.tools.sources import read_source

    for path in (source, reference):
        if path is not None:
            require_utf8_path(path)
    if not source.exists():
        raise InputError(source, "no such file or folder")
    sha = _source_hash(source)
    key = f"{sha}:{reference.resolve() if reference else ''}"
    if store.has_source(key):
        return 0
    if source.suffix.lower() == ".jsonl":
        rows = read_edge_rows(source)
        check_viewable(rows, source)  # before the server starts, not as a blank tab
        edges = [edge for _, edge in rows]
        kind = "edges"
    else:
        found = read_source(
            source, options, reference, time_offset=time_offset, max_loops=max_loops
        )
        typer.echo(f"making candidate edges of {source} (once; kept in {store.workspace})")
        edges = make_candidates(
            found.log,
            ScanMatcher(),
            CandidateConfig(max_loops=max_loops),
            relations=found.relations,
            params=found.params,
        )
        kind = "log"
    if not edges:
        raise InputError(source, "gives no candidate edges to label")
    return store.add_edges(edges, source=(key, str(source.resolve()), kind))


def predict_workspace(store: LabelStore, model: Path, progress: bool = True) -> None:
    """Stores the model's p(success) for every edge, unless this model's are there already."""
    from vgm_studio.model import Validator
    from vgm_studio.trainer import list_models

    if list_models(store):
        return  # the workspace's own trainer has versions: the active one stays in use
    key = f"{model.name}:{file_hash(model)[:12]}"
    current = store.predictions()
    if current.model == key and len(current.p) == store.count_edges():
        return
    validator = Validator.load(model)
    edges = store.edges()
    if progress:
        typer.echo(f"predicting p(success) of {len(edges)} edges with {model.name}")
    p = validator.predict(edges, progress=progress)
    store.set_predictions(
        key, dict(zip((e.edge_id for e in edges), p, strict=True)), validator.threshold
    )


@dataclass
class TrainerOptions:
    """The background trainer beside the studio (see ``vgm_studio.trainer``)."""

    retrain_every: int = 25
    base: list[Path] = field(default_factory=list)


def _start_trainer(studio: Studio, options: TrainerOptions) -> Callable[[], None]:
    """Starts the trainer process and the watcher that brings its versions to the app.

    Returns:
        A function that stops both.
    """
    from vgm_studio.studio.panel import trainer_text
    from vgm_studio.trainer import PromotionWatcher, TrainerSupervisor, request_training

    store = studio.store
    supervisor = TrainerSupervisor(store.workspace, options.retrain_every, options.base)
    watcher = PromotionWatcher(
        store,
        on_promote=lambda _name: studio.refresh_predictions(),
        on_status=lambda status: studio.show_trainer(trainer_text(status)),
    )

    def train_now() -> None:
        request_training(store)

    studio.train_now = train_now
    supervisor.start()
    watcher.start()

    def stop() -> None:
        watcher.stop()
        supervisor.stop()

    return stop


def serve(
    store: LabelStore,
    config: StudioConfig,
    *,
    model: Path | None = None,
    trainer: TrainerOptions | None = None,
    ready_seconds: float | None = None,
) -> None:
    """Starts the studio (and the trainer beside it), says where, and serves until Ctrl-C.

    The model's predictions are made in the background: the annotator can start at once, and
    p(success) appears in the panel when they are ready.
    """
    studio = Studio(store, config)
    studio.start()
    stop_trainer = _start_trainer(studio, trainer) if trainer is not None else None
    if model is not None:
        threading.Thread(
            target=_predict_then_refresh, args=(studio, model), daemon=True, name="predict"
        ).start()
    when = f" (ready {ready_seconds:.1f} s after start)" if ready_seconds is not None else ""
    typer.echo(f"VGM Studio: {store.count_edges()} edges at {studio.url}{when}")
    typer.echo("  keys: S success · F failure · D skip · Z undo · Q previous · E next · G guess")
    if config.host not in ("127.0.0.1", "localhost", "::1"):
        typer.echo("  warning: " + EXPOSED.format(host=config.host, port=config.port), err=True)
    typer.echo("  Ctrl-C stops; every label is already saved.")
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        typer.echo("stopped; labels are in " + str(store.path))
    finally:
        if stop_trainer is not None:
            stop_trainer()
        studio.stop()
        store.close()


WorkspaceOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="DIR", help="Workspace folder (label store).", show_default="SOURCE-name.studio"
    ),
]
PortOpt = Annotated[int, typer.Option(help="TCP port.", min=1, max=65535)]
HostOpt = Annotated[
    str, typer.Option(help="Interface to listen on; anything but 127.0.0.1 exposes the labels.")
]
NoTrainerOpt = Annotated[
    bool, typer.Option("--no-trainer", help="Run no background trainer beside the studio.")
]
RetrainOpt = Annotated[
    int, typer.Option(help="The trainer trains after this many new labels.", min=1)
]
BaseOpt = Annotated[
    list[Path] | None,
    typer.Option("--base", metavar="EDGES.jsonl", help="Labelled edges the trainer also uses."),
]
AnnotatorOpt = Annotated[
    str | None, typer.Option(help="Your name on the labels.", show_default="your login")
]


def label(
    source: Annotated[
        Path,
        typer.Argument(metavar="SOURCE", help="A log (CARMEN, ROS bag) or an EDGES.jsonl file."),
    ],
    reference: Annotated[
        Path | None,
        typer.Option(metavar="REF", help="Reference for a log: corrected log or relations."),
    ] = None,
    workspace: WorkspaceOpt = None,
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
    no_model: Annotated[bool, typer.Option(help="Show no model predictions.")] = False,
    no_trainer: NoTrainerOpt = False,
    retrain_every: RetrainOpt = 25,
    base: BaseOpt = None,
    max_loops: Annotated[int, typer.Option("--max", help="Loop candidates at most.", min=1)] = 2000,
    time_offset: Annotated[
        float, typer.Option(help="Seconds added to a reference log's timestamps.")
    ] = 0.0,
    poses: Annotated[str, typer.Option(help="auto, odometry or reference.")] = "auto",
    skip_bad_lines: Annotated[bool, typer.Option(help="Skip malformed log lines.")] = False,
) -> None:
    """Serve a log's candidate edges (or an edges file) in the browser for labeling."""
    start = time.perf_counter()
    if poses not in ("auto", "odometry", "reference"):
        raise typer.BadParameter(f"{poses!r} is not one of auto, odometry, reference.")
    check_host(host)
    check_port_free(host, port)
    store = LabelStore(workspace or Path(f"{source.stem}.studio"))
    options = ReadOptions(poses=cast(PoseSource, poses), skip_bad_lines=skip_bad_lines)
    fill_workspace(store, source, reference, options, max_loops, time_offset)
    model_path = _model_path(model, no_model)
    trainer = _trainer_options(no_trainer, retrain_every, base)
    config = StudioConfig(host=host, port=port, annotator=annotator or default_annotator())
    serve(
        store, config, model=model_path, trainer=trainer, ready_seconds=time.perf_counter() - start
    )


def _trainer_options(
    no_trainer: bool, retrain_every: int, base: list[Path] | None
) -> TrainerOptions | None:
    """Checks the trainer's options now: a base file missing would crash it over and over."""
    if no_trainer:
        return None
    for path in base or []:
        if not path.is_file():
            raise InputError(path, "no such --base edges file")
    return TrainerOptions(retrain_every, [p.resolve() for p in base or []])


def _predict_then_refresh(studio: Studio, model: Path) -> None:
    try:
        predict_workspace(studio.store, model, progress=False)
    except Exception as exc:  # a failed model must not take the labeling down
        typer.echo(f"{model}: no predictions ({exc})", err=True)
        return
    studio.refresh_predictions()


def _model_path(model: Path | None, no_model: bool) -> Path | None:
    """The model to predict with: the one named, else the bundled one; checked now."""
    if no_model:
        return None
    path = model or DEFAULT_MODEL
    if not path.is_file():
        if model is not None:
            raise InputError(model, "no such model file")
        typer.echo(f"{path}: bundled model missing; showing no predictions", err=True)
        return None
    from vgm_studio.model.checkpoint import load_checkpoint

    load_checkpoint(path)  # refuses a foreign or damaged file before the server starts
    return path


def demo(
    workspace: Annotated[Path, typer.Option(metavar="DIR", help="Workspace folder.")] = Path(
        "vgm-demo"
    ),
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
    start = time.perf_counter()
    if not DEMO_LOG.exists():
        raise InputError(
            DEMO_LOG,
            "bundled demo log missing; remake it with: "
            "vgm-studio simulate --out datasets --preset demo --seed 0",
        )
    if serve_app:
        check_host(host)
    check_port_free(host, port)
    store = LabelStore(workspace)
    fill_workspace(store, DEMO_LOG, None, ReadOptions(), max_loops=DEMO_LOOPS)
    model = _model_path(None, False)
    if not serve_app:
        if model is not None:
            predict_workspace(store, model)
        seconds = time.perf_counter() - start
        typer.echo(f"workspace {workspace} ready: {store.count_edges()} edges ({seconds:.1f} s)")
        store.close()
        return
    trainer = _trainer_options(no_trainer, retrain_every, None)
    config = StudioConfig(host=host, port=port, annotator=annotator or default_annotator())
    serve(store, config, model=model, trainer=trainer, ready_seconds=time.perf_counter() - start)


def export(
    workspace: Annotated[Path, typer.Option(metavar="DIR", help="Workspace folder.")],
    out: Annotated[Path, typer.Option(metavar="FILE", help="Labels file: .jsonl or .csv.")],
) -> None:
    """Write a workspace's labels as JSONL (a training file) or CSV."""
    from vgm_studio.labels.transfer import export_labels

    store = LabelStore(workspace, create=False)
    count = export_labels(store, out)
    typer.echo(f"wrote {count} labels to {out}")


def import_(
    files: Annotated[list[Path], typer.Argument(metavar="FILE...", help="Exported label files.")],
    workspace: Annotated[Path, typer.Option(metavar="DIR", help="Workspace folder.")],
) -> None:
    """Add exported labels (.jsonl or .csv) to a workspace; the newer label wins."""
    from vgm_studio.labels.transfer import import_labels

    store = LabelStore(workspace)
    for path in files:
        edges, labels = import_labels(store, path)
        typer.echo(f"{path}: {labels} labels added or updated, {edges} new edges")
