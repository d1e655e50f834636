"""Leave-one-building-out: each real building's loops judged by models that never saw it.

For each of the eleven buildings (Intel from ``intel.gfs.log``, the ten of
``radish-corrected/``) the models are trained on the other ten and the simulated worlds
(``edge_sets.py``) and tested on the held-out building's loop candidates (the benchmark
protocol: 2000 loops, seed 0, loops only). Per building and model: accuracy, F1, AUC,
precision and false positives at the threshold chosen on validation, and recall at
precision ≥ 0.99 twice: at the cut the validation curve picks for 0.99 (what
``--loop-precision 0.99`` would use; its test precision beside it) and the best any cut on
the test curve reaches (an upper bound, chosen on the test set).

The table ends with the paired comparison of ``vgmnet`` and ``rgb-baseline`` per building:
the loops only one of them judged right, and the exact McNemar p of that split, so a lead of
one or two loops on a small building reads as what it is.

``vgmnet``'s fold models draw each side of a pair as the bundled model does (its local maps,
``model.context.DEFAULT_CONTEXT``); the other models read single scans. The edges are read
once per way of drawing them.

Fold models already in build/edges/folds are used again (a stopped run goes on with the next
one; ``--retrain`` trains them all again); one drawn another way is trained again. A
``vgmnet`` fold on cells other than 5 cm has its grid in the file name
(``intel-vgmnet-cell0.1.pt``), so both grids' folds are kept.

Run: python benchmarks/bench_generalisation.py [--models vgmnet,score] [--buildings orebro]
     [--epochs 12 | --epochs vgmnet=12,rgb-baseline=4] [--epoch-size 6000] [--max-train N]
     [--retrain] [--second-look 4] [--cell 0.1] [--jobs 2 --threads 1]

``--jobs 2 --threads 1`` trains two fold models at once, each in a process on one torch
thread: on two cores that is about 1.8× the throughput for ``vgmnet`` (its small network
gains little from a second thread) and 1.3× for ``rgb-baseline``. The workers load the edges
the parent read, so the reading is done once. With both networks at two-thirds of their
recipes as well (``--epochs vgmnet=20,rgb-baseline=4``) the whole table takes about 43 minutes
on two cores; at the full recipes, about 67 (BENCHMARKS.md).

``--second-look 4`` tests the network models with ``validator.SecondLook``: the pairs they
are unsure of (p between 0.02 and 0.98) judged again, their logits averaged over the pair
turned four ways.
"""

from __future__ import annotations

import argparse
import pickle
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from _common import (
    RGB_CPU_RECIPE,
    datasets_dir,
    machine,
    pin_to_cores,
    spawned,
    table,
    watch_parent,
)
from edge_sets import BUILD, training_edges
from folds import Building, make_folds
from numpy.typing import NDArray
from recalibrate import recalibrate

if TYPE_CHECKING:
    from vgm_studio.model.registry import HyperFlags
    from vgm_studio.model.training import TrainConfig

MODELS = ("vgmnet", "rgb-baseline", "score")
# Per (building, model): which of the building's test loops the model judged right.
Judged = dict[tuple[str, str], NDArray[np.bool_]]
PRECISION = 0.99
# Epochs and draws per epoch of a fold model unless --epochs/--epoch-size say otherwise:
# the recipes of the Intel table (bench_models.py on a CPU), so a fold's models are trained
# as the bundled ones were: TrainConfig's defaults, but fewer, smaller epochs for the RGB
# baseline on a CPU.
CPU_RECIPES = {"rgb-baseline": RGB_CPU_RECIPE}


def _recipe(model: str) -> tuple[int, int | None]:
    from vgm_studio.model.training import TrainConfig

    defaults = TrainConfig()
    return CPU_RECIPES.get(model, (defaults.epochs, defaults.epoch_size))


def fold_config(
    model: str,
    epochs: int | None = None,
    epoch_size: int | None = None,
    cell: float | None = None,
    inputs: HyperFlags | None = None,
    **overrides: Any,
) -> TrainConfig:
    """How a fold's ``model`` is trained: its recipe (``epochs`` and ``epoch_size`` where
    given), the inputs ``vgm-studio train``'s switches ``inputs`` give (None: the bundled
    default's), ``vgmnet`` on ``cell`` metre cells (None: the paper's); ``overrides`` set any
    other ``TrainConfig`` field."""
    from vgm_studio.model.context import DEFAULT_CONTEXT, Context
    from vgm_studio.model.registry import HyperFlags, entry
    from vgm_studio.model.training import TrainConfig
    from vgm_studio.vgm.grid import VGMParams

    recipe_epochs, recipe_size = _recipe(model)
    # vgmnet's pairs drawn as the bundled model's are (local maps); the others single scans.
    overrides.setdefault("context", DEFAULT_CONTEXT if model == "vgmnet" else Context())
    return TrainConfig(
        model=model,
        epochs=epochs or recipe_epochs,
        epoch_size=epoch_size or recipe_size,
        # Unasked, the bundled default's inputs (train_default.py: the command's defaults).
        hyper=entry(model).hyper(inputs or HyperFlags()),
        vgm=VGMParams(resolution=cell) if model == "vgmnet" and cell else VGMParams(),
        **overrides,
    )


def grid_tag(model: str, cell: float | None) -> str:
    """What a fold file's name says of its grid: nothing on the paper's cells (or unset),
    else ``-cell0.1`` and the like, so fold models on both grids are kept side by side."""
    from vgm_studio.vgm.grid import VGMParams

    if model != "vgmnet" or cell is None or cell == VGMParams().resolution:
        return ""
    return f"-cell{cell:g}"


def _candidates(log: Path, out: Path, *args: str) -> Path:
    if not out.exists():
        subprocess.run(
            [sys.executable, "-m", "vgm_studio.tools.cmd", "candidates", log, *args, "--out", out],
            check=True,
            stdout=subprocess.DEVNULL,
        )
    return out


def buildings(held_out: list[str]) -> tuple[list[Building], list[Path]]:
    """The eleven buildings' edge files and the simulated worlds'; training files and the
    held-out buildings' loop files are made on first use."""
    train = training_edges()
    logs = {
        p.stem.removesuffix("-corrected"): p
        for p in (datasets_dir() / "radish-corrected").glob("*.log")
    }
    intel = datasets_dir() / "intel" / "intel.gfs.log"
    made = []
    for name, log in sorted(logs.items()):
        loops = BUILD / "loops" / f"{log.stem}.jsonl"
        if name in held_out:
            _candidates(log, loops, "--no-sequential")
        made.append(Building(name, BUILD / "train" / f"{log.stem}.jsonl", loops))
    loops = BUILD / "test" / "intel-loops.jsonl"
    if "intel" in held_out:
        _candidates(intel, loops, "--no-sequential")
    made.append(Building("intel", _candidates(intel, BUILD / "train-intel" / "intel.jsonl"), loops))
    return made, [p for p in train if p.name.startswith("sim-")]


def subset(data, origin: list[str], files: list[Path]):
    """The labelled set restricted to the edges read from ``files`` (``origin``: each
    edge's file)."""
    from vgm_studio.model.training import LabelledSet

    wanted = {str(f) for f in files}
    keep = [i for i, path in enumerate(origin) if path in wanted]
    return LabelledSet(
        [data.edges[i] for i in keep],
        [data.samples[i] for i in keep],
        data.labels[keep],
        [f for f in data.files if f["path"] in wanted],
        data.context,
    )


def _row(building: str, model: str, labels, probs, checkpoint, seconds: float) -> list[str]:
    from vgm_studio.errors import InputError
    from vgm_studio.model.checkpoint import precision_threshold
    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.operating import precision_curve

    m = binary_metrics(labels, probs, checkpoint.threshold)
    try:
        cut = precision_threshold(checkpoint, PRECISION, None)
        mc = binary_metrics(labels, probs, cut)
        passed = f"P {mc['precision']:.3f}" if mc["tp"] + mc["fp"] else "none passed"
        at_val = f"{mc['recall']:.3f} ({passed})"
    except InputError:  # validation never reached the precision
        at_val = "— (not reached on validation)"
    test = precision_curve(labels, probs)
    reach = [r for p, r in zip(test.precision, test.recall, strict=True) if p >= PRECISION]
    return [
        building,
        model,
        str(len(labels)),
        f"{m['accuracy']:.4f}",
        f"{m['f1']:.4f}",
        f"{m['auc']:.4f}",
        f"{m['precision']:.4f}",
        str(m["fp"]),
        at_val,
        f"{max(reach):.3f}" if reach else "0",
        f"{seconds / 60:.1f}",
    ]


def _judge(fold, model: str, read: dict, origin: list[str], args) -> tuple[list[str], Any]:
    """Trains ``model`` on the fold's training files (or takes the fold model already there)
    and tests it on the held-out loops; ``read`` holds the edges read with each context the
    models draw with. Returns the table row and which test pairs the model judged right."""
    from vgm_studio.model.checkpoint import load_checkpoint
    from vgm_studio.model.training import train
    from vgm_studio.model.validator import SecondLook, Validator

    out = BUILD / "folds" / f"{fold.held_out}-{model}{grid_tag(model, args.cell)}.pt"
    out.parent.mkdir(parents=True, exist_ok=True)  # a fresh clone has no build/ yet
    config = fold_config(
        model,
        args.epochs.get(model),
        args.epoch_size,
        args.cell,
        max_train=args.max_train,
        device="cpu",
        threads=args.threads,
    )
    data = read[config.context]
    test = subset(data, origin, [fold.test])
    training = subset(data, origin, fold.train)
    kept = load_checkpoint(out) if out.exists() else None
    # A fold model on other VGMs (another --cell) or other sides (another recipe's local
    # maps) is trained again, not reused.
    if args.retrain or kept is None or (kept.vgm, kept.context) != (config.vgm, config.context):
        train(training, config, out, progress=False, log=lambda _line: None)
    elif "calibration_edges" not in kept.training:
        print(recalibrate(out, training), flush=True)  # trained before the rule
    checkpoint = load_checkpoint(out)
    start = time.perf_counter()
    look = SecondLook(turns=args.second_look) if model != "score" else None
    probs = Validator.load(out, device="cpu", second_look=look).predict_samples(test.samples)
    # Training (as the checkpoint recorded it) and testing.
    seconds = checkpoint.training["seconds"] + time.perf_counter() - start
    row = _row(fold.held_out, model, test.labels, probs, checkpoint, seconds)
    return row, (probs >= checkpoint.threshold) == test.labels


# A pool worker's edges and folds, loaded once by _start_worker.
_WORKER: dict[str, Any] = {}


def _start_worker(args, store: Path, folds: list) -> None:
    import torch

    watch_parent()
    torch.set_num_threads(args.threads)
    with store.open("rb") as f:
        _WORKER.update(pickle.load(f), args=args, folds={f.held_out: f for f in folds})


def _pool_job(job: tuple[str, str]) -> tuple[str, str, list[str], Any]:
    building, model = job
    w = _WORKER
    row, right = _judge(w["folds"][building], model, w["read"], w["origin"], w["args"])
    return building, model, row, right


def _judge_all(
    folds, read: dict, origin: list[str], models: list[str], args
) -> dict[tuple[str, str], tuple[list[str], Any]]:
    """Every (building, model)'s row and judgements (``_judge``), printed as each ends;
    ``args.jobs`` at once in spawned processes, which load the edges the parent read (a
    pickle in build/) rather than read them again."""
    done = {}
    if args.jobs == 1:
        for fold in folds:
            for model in models:
                done[fold.held_out, model] = _judge(fold, model, read, origin, args)
                print(" | ".join(done[fold.held_out, model][0]), flush=True)
        return done
    # Model by model (MODELS' order), each model's folds on the largest training sets (the
    # smallest buildings held out) first, so the last jobs to finish are short: score's.
    size = {f.held_out: sum(p.stat().st_size for p in f.train) for f in folds}
    jobs = sorted(
        ((f.held_out, m) for f in folds for m in models),
        key=lambda j: (MODELS.index(j[1]), -size[j[0]]),
    )
    # One name, not a fresh temporary file: a run killed outright leaves its edges (most of
    # a gigabyte) for the next run to write over, not beside.
    store = BUILD / "lobo-reading.pickle"
    try:
        with store.open("wb") as f:
            pickle.dump({"read": read, "origin": origin}, f, protocol=pickle.HIGHEST_PROTOCOL)
        for building, model, row, mine in spawned(
            _pool_job, jobs, args.jobs, _start_worker, (args, store, folds)
        ):
            done[building, model] = row, mine
            print(" | ".join(row), flush=True)
    finally:
        store.unlink(missing_ok=True)
    return done


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--models", default=",".join(MODELS), help="Comma-separated models.")
    parser.add_argument("--buildings", default="", help="Comma-separated held-out buildings.")
    parser.add_argument(
        "--epochs",
        type=_epochs,
        default={},
        help="Epochs per fold model: one number for every network, or per model "
        "(vgmnet=12,rgb-baseline=4); unset, each model's recipe.",
    )
    parser.add_argument("--epoch-size", type=int, default=None, help="Draws per epoch.")
    parser.add_argument("--max-train", type=int, default=None, help="Cap training edges.")
    parser.add_argument(
        "--retrain", action="store_true", help="Train fold models again even if present."
    )
    parser.add_argument(
        "--cell",
        type=float,
        default=0.05,
        help="vgmnet's VGM cell edge in metres (vgm-studio train --cell-size; 0.1: 40 m VGMs).",
    )
    parser.add_argument(
        "--second-look",
        type=int,
        default=1,
        metavar="TURNS",
        help="Look again at the pairs a network is unsure of, its logits averaged over the "
        "pair turned TURNS ways (validator.SecondLook; 1: off).",
    )
    parser.add_argument(
        "--jobs", type=int, default=1, help="Fold models trained at once, each in a process."
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="torch threads per fold model (unset: the cores the process may use).",
    )
    args = parser.parse_args()
    began = time.perf_counter()
    if args.jobs < 1 or (args.threads is not None and args.threads < 1):
        raise SystemExit("--jobs and --threads must be 1 or more")
    if args.second_look < 1:
        raise SystemExit("--second-look: TURNS must be 1 or more")
    pin_to_cores(2)
    from vgm_studio.model.training import read_labelled

    models = [m for m in args.models.split(",") if m]
    unknown = sorted(set(models) - set(MODELS))
    if unknown:
        raise SystemExit(f"--models: unknown {', '.join(unknown)}; known: {', '.join(MODELS)}")
    names = [
        "intel",
        *sorted(
            p.stem.removesuffix("-corrected")
            for p in (datasets_dir() / "radish-corrected").glob("*.log")
        ),
    ]
    held_out = [b for b in args.buildings.split(",") if b] or names
    made, sims = buildings(held_out)
    try:
        folds = make_folds(made, sims, held_out)
    except ValueError as exc:
        raise SystemExit(f"--buildings: {exc}") from None
    files = sorted({p for f in folds for p in f.train} | {f.test for f in folds})
    # Each context the models draw their pairs with, read once (local maps take minutes).
    contexts = {fold_config(m).context for m in models}
    read = {c: read_labelled(files, progress=False, context=c) for c in contexts}
    reading = (time.perf_counter() - began) / 60
    data = next(iter(read.values()))
    # Which file each edge came from: read_labelled keeps the files' order and each file's.
    origin = [f["path"] for f in data.files for _ in range(f["used"])]
    done = _judge_all(folds, read, origin, models, args)
    # The table and the paired comparison read the buildings in fold order.
    order = [(f.held_out, m) for f in folds for m in models]
    rows = [done[key][0] for key in order]
    right: Judged = {key: done[key][1] for key in order}
    wall = (time.perf_counter() - began) / 60
    print(
        "\n# leave-one-building-out, loops of each held-out building; epochs × draws per fold "
        + ", ".join(
            f"{m} {args.epochs.get(m) or _recipe(m)[0]} × {args.epoch_size or _recipe(m)[1]}"
            for m in models
            if m != "score"
        )
        + (f", at most {args.max_train} training edges" if args.max_train else "")
        + (f"; vgmnet on {args.cell:g} m cells" if "vgmnet" in models else "")
        + (f", its pairs drawn with {fold_config('vgmnet').context}" if "vgmnet" in models else "")
        + (f"; a second look over {args.second_look} turns" if args.second_look > 1 else "")
        + f"; 2 CPU cores, {args.jobs} fold model(s) at a time"
        + (f", {args.threads} torch thread(s) each" if args.threads else "")
    )
    print(f"# whole table {wall:.1f} min of wall time, reading the edges {reading:.1f} min")
    print(f"# {machine()}")
    header = ["held out", "model", "loops", "accuracy", "F1", "AUC", "precision", "FP"]
    header += [f"recall @ val cut P≥{PRECISION}", f"best recall @ test P≥{PRECISION}", "min"]
    print(table(header, rows))
    _summary(rows, models)
    _paired(right)


def _epochs(text: str) -> dict[str, int]:
    """``--epochs``: ``12`` for every network, or ``vgmnet=12,rgb-baseline=4``."""
    try:
        if "=" in text:
            pairs = dict(part.split("=", 1) for part in text.split(",") if part)
            epochs = {model: int(n) for model, n in pairs.items()}
        else:
            epochs = dict.fromkeys(MODELS, int(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of epochs: {text!r}") from None
    unknown = sorted(set(epochs) - set(MODELS))
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown model {', '.join(unknown)}")
    if min(epochs.values(), default=1) < 1:
        raise argparse.ArgumentTypeError("epochs must be 1 or more")
    return epochs


def _summary(rows: list[list[str]], models: list[str]) -> None:
    """Per model: mean and lowest accuracy over the held-out buildings (the issue's targets)."""
    acc = {(r[0], r[1]): float(r[3]) for r in rows}
    for model in models:
        mine = [a for (_, m), a in acc.items() if m == model]
        if mine:
            print(f"{model}: mean accuracy {sum(mine) / len(mine):.4f}, lowest {min(mine):.4f}")


def _paired(right: Judged) -> None:
    """Per building, the loops only ``vgmnet`` or only ``rgb-baseline`` judged right, and
    whether that split is more than chance (exact McNemar test): on a building of 50 loops
    one pair moves accuracy by 0.02."""
    from vgm_studio.model.metrics import paired_comparison

    rows = []
    ahead = beyond = behind = 0
    for (building, model), mine in right.items():
        if model != "vgmnet" or (building, "rgb-baseline") not in right:
            continue
        c = paired_comparison(mine, right[building, "rgb-baseline"])
        lead = c.only_first - c.only_second
        verdict = "level" if lead == 0 else ("vgmnet" if lead > 0 else "rgb-baseline")
        if lead and c.p_value >= 0.05:
            verdict += " (chance can explain it)"
        # More loops right is higher accuracy on the same loops: the "ahead".
        ahead += lead > 0
        beyond += lead > 0 and c.p_value < 0.05
        behind += lead < 0 and c.p_value < 0.05
        rows.append([building, str(c.only_first), str(c.only_second), f"{c.p_value:.3f}", verdict])
    if rows:
        header = ["held out", "only vgmnet right", "only rgb-baseline right", "exact p", "ahead"]
        print(table(header, rows))
        print(
            f"vgmnet ahead of rgb-baseline on accuracy: {ahead} of {len(rows)} buildings "
            f"({beyond} beyond chance); behind beyond chance on {behind}"
        )


if __name__ == "__main__":
    sys.exit(main())
