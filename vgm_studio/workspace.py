"""A workspace's edges and predictions: filled from a log or an edges file, scored by a model.

A workspace is a folder with a label store (``labels/``). Filling it makes a log's candidate
edges once (a source is known by its content, not its path); predicting stores a model's
p(success) for every edge, unless the workspace's own trainer has versions of its own.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from vgm_studio.core.hashing import content_hash
from vgm_studio.datasets import ReadOptions
from vgm_studio.datasets.source import JoinOptions, read_source
from vgm_studio.errors import InputError, require_utf8_path
from vgm_studio.labels.opening import store_to_fill
from vgm_studio.labels.store import LabelStore
from vgm_studio.matching.candidates import CandidateConfig, make_candidates
from vgm_studio.matching.edge_scans import check_viewable
from vgm_studio.matching.edges import read_edge_rows
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.model.checkpoint import load_checkpoint, precision_threshold
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.model.validator import Validator

REPO = Path(__file__).resolve().parents[1]
DEMO_LOG = REPO / "datasets" / "demo-seed0.log"
# Enough loop candidates to label for a while, few enough that the demo serves within seconds.
DEMO_LOOPS = 600

Say = Callable[[str], None]


def _quiet(_line: str) -> None:
    return None


def source_key(source: Path, reference: Path | None) -> str:
    """What a source is known by in the store: its content, and the reference's path."""
    return f"{content_hash(source)}:{reference.resolve() if reference else ''}"


def check_source(source: Path, reference: Path | None = None) -> None:
    """Refuses a source or reference that is not there (or whose path is not UTF-8), before
    anything is made for it.

    Raises:
        InputError: Naming the path.
    """
    for path in (source, reference):
        if path is not None:
            require_utf8_path(path)
    if not source.exists():
        raise InputError(source, "no such file or folder")
    if reference is not None and not reference.exists():
        raise InputError(reference, "no such reference file")


def fill_workspace(
    store: LabelStore,
    source: Path,
    reference: Path | None,
    options: ReadOptions,
    max_loops: int = 2000,
    join: JoinOptions | None = None,
    *,
    say: Say = _quiet,
    warn: Say = _quiet,
) -> int:
    """Adds a log's candidate edges (made now, once per log) or an edges file to the store.

    Args:
        store: The workspace's store.
        source: A log (CARMEN, ROS bag) or an edges file (``.jsonl``).
        reference: A log's reference: a corrected log, a TRUEPOS log or relations.
        options: How to read the log.
        max_loops: Loop candidates at most.
        join: How a reference log's timestamps are joined to the scans.
        say: Told what is being made.
        warn: Told what went amiss in reading.

    Returns:
        How many edges were new.
    """
    check_source(source, reference)
    key = source_key(source, reference)
    if options.laser_pose is not None or options.laser_flipped:
        # Another mount places the scans elsewhere: other edges, not the ones already there.
        key += f":{options.laser_pose}:{options.laser_flipped}"
    if store.has_source(key):
        return 0
    if source.suffix.lower() == ".jsonl":
        rows = read_edge_rows(source)
        check_viewable(rows, source)  # before the server starts, not as a blank tab
        edges = [edge for _, edge in rows]
        kind = "edges"
    else:
        found = read_source(source, options, reference, join or JoinOptions(), max_loops)
        for line in found.warnings:
            warn(line)
        say(f"making candidate edges of {source} (once; kept in {store.workspace})")
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


def predict_workspace(
    store: LabelStore, model: Path, *, precision: float | None = None, say: Say = _quiet
) -> None:
    """Stores the model's p(success) for every edge, unless this model's are there already.

    The studio's decisions (what the model says, the "model disagrees" queue) use the
    checkpoint's threshold, or with ``precision`` the lowest cut whose validation precision
    reaches it. A workspace whose trainer has versions keeps the active one: nothing is done
    then.
    """
    if store.versions.all():
        return
    key = f"{model.name}:{content_hash(model)[:12]}"
    if precision is not None:
        key += f"@precision{precision:g}"
    current = store.predictions()
    if current.model == key and len(current.p) == store.count_edges():
        return
    validator = Validator.load(model)
    edges = store.edges()
    say(f"predicting p(success) of {len(edges)} edges with {model.name}")
    threshold = validator.threshold
    if precision is not None:
        threshold = validator.threshold_at_precision(precision)
    p = validator.predict(edges, progress=say is not _quiet)
    store.set_predictions(key, dict(zip((e.edge_id for e in edges), p, strict=True)), threshold)


def choose_model(
    model: Path | None,
    no_model: bool = False,
    *,
    precision: float | None = None,
    warn: Say = _quiet,
) -> Path | None:
    """The model to predict with: the one named, else the bundled one; checked now.

    Raises:
        InputError: The named model is missing, or no VGM Studio checkpoint, or
            ``precision`` is asked for and its validation curve cannot give it.
    """
    if no_model:
        return None
    path = model or BUNDLED_MODEL
    if not path.is_file():
        if model is not None:
            raise InputError(model, "no such model file")
        warn(f"{path}: bundled model missing; showing no predictions")
        return None
    checkpoint = load_checkpoint(path)  # refuses a foreign or damaged file before serving
    if precision is not None:
        precision_threshold(checkpoint, precision, path)
    return path


def open_demo(
    workspace: Path,
    url: str | None = None,
    *,
    predict: bool = False,
    precision: float | None = None,
    say: Say = _quiet,
    warn: Say = _quiet,
) -> tuple[LabelStore, Path | None]:
    """The demo workspace (or team store at ``url``), filled from the bundled demo log; with
    the bundled model's predictions stored when ``predict`` (else the server makes them in
    the background). A workspace made here is removed again when this fails.

    Returns:
        The store and the bundled model (None when it is missing).

    Raises:
        InputError: The bundled demo log is missing.
    """
    if not DEMO_LOG.exists():
        raise InputError(
            DEMO_LOG,
            "bundled demo log missing; remake it with: "
            "vgm-studio simulate --out datasets --preset demo --seed 0",
        )
    model = choose_model(None, precision=precision, warn=warn)
    with store_to_fill(workspace, url) as store:
        fill_workspace(
            store, DEMO_LOG, None, ReadOptions(), max_loops=DEMO_LOOPS, say=say, warn=warn
        )
        if predict and model is not None:
            predict_workspace(store, model, precision=precision, say=say)
    return store, model
