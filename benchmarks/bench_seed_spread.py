"""How much of the leave-one-building-out comparison is the training seed.

``bench_generalisation.py`` trains one ``vgmnet`` and one ``rgb-baseline`` per fold, each
with seed 0, and counts the buildings where ``vgmnet`` is ahead. On the small buildings the
two disagree on one to six loops, so that count may turn on the seeds. This script trains
each fold's two networks again with other seeds (the same recipes, files and second look as
that table) and prints, per building, each seed's accuracy, and the count of buildings
``vgmnet`` is ahead on for every pairing of a ``vgmnet`` seed with an ``rgb-baseline`` one.

Many folds at once: ``--jobs`` processes, each loading the edges once, share one device;
on a CPU give each process ``--threads`` of the cores. Each job writes its fold model and
its test judgements under ``--out``, so a stopped run goes on with the next job, and
``--summary`` prints the tables from whatever is there.

Run: python benchmarks/bench_seed_spread.py [--seeds 1,2] [--jobs 8] [--device cuda]
     [--cell 0.1] [--out build/seeds] [--summary]
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from _common import REPO, machine, spawned, table, watch_parent
from bench_generalisation import buildings, fold_config, grid_tag, subset
from folds import Fold, make_folds
from numpy.typing import NDArray

from vgm_studio.model.registry import HyperFlags, entry

NETWORKS = ("vgmnet", "rgb-baseline")
# ``--inputs``: what ``vgmnet`` reads besides the VGM, as ``vgm-studio train``'s switches
# (``--no-figures``, ``--no-inliers``, ``--no-blind-head``); an ablation's fold models are kept
# beside the default's. Before 2026-12-05 the default had no blind head and ``blind-head`` was
# the ablation: those draws are ``default`` now, and the old default is ``no-blind-head``.
INPUTS: dict[str, HyperFlags] = {
    "default": HyperFlags(),
    "no-figures": HyperFlags(figures=False),
    "variances": HyperFlags(inliers=False, blind=False),
    "no-blind-head": HyperFlags(blind=False),
}


def _stem(
    building: str,
    model: str,
    seed: int,
    inputs: str,
    cell: float | None = None,
    occlude: float = 0.0,
    context: int = 0,
    covisible: bool = False,
) -> str:
    tag = f"{model}-{inputs}" if model == "vgmnet" and inputs != "default" else model
    cuts = f"-occlude{occlude:g}" if model == "vgmnet" and occlude else ""
    near = f"-context{context}" if model == "vgmnet" and context else ""
    near += "-covisible" if near and covisible else ""
    return f"{building}-{tag}{grid_tag(model, cell)}{cuts}{near}-seed{seed}"


@dataclass
class _Loaded:
    """One process's edges: every fold's training and test files, read once."""

    args: argparse.Namespace
    folds: dict[str, Fold]
    data: Any  # training.LabelledSet, imported late so --help stays fast
    origin: list[str]  # the file each edge came from


_LOADED: list[_Loaded] = []  # this process's, set by _load


def _load(args: argparse.Namespace) -> list[str]:
    """Reads every fold's edges into this process; the held-out buildings, in fold order."""
    from vgm_studio.model.context import Context
    from vgm_studio.model.training import read_labelled

    folds = _folds(args)
    files = sorted({p for f in folds for p in f.train} | {f.test for f in folds})
    context = Context(neighbours=args.context, covisible=args.covisible)
    data = read_labelled(files, progress=False, context=context)
    origin = [f["path"] for f in data.files for _ in range(f["used"])]
    _LOADED[:] = [_Loaded(args, {f.held_out: f for f in folds}, data, origin)]
    return [f.held_out for f in folds]


def _folds(args: argparse.Namespace) -> list[Fold]:
    made, sims = buildings([])
    try:
        return make_folds(made, sims, [b for b in args.buildings.split(",") if b] or None)
    except ValueError as exc:
        raise SystemExit(f"--buildings: {exc}") from None


def _job(job: tuple[str, str, int]) -> str:
    """Trains one fold model with one seed and writes its test judgements; one line back."""
    import torch

    from vgm_studio.atomic import write_json_atomically
    from vgm_studio.model.training import train
    from vgm_studio.model.validator import SecondLook, Validator

    building, model, seed = job
    loaded = _LOADED[0]
    args = loaded.args
    occlude = args.occlude if model == "vgmnet" else 0.0  # rgb-baseline is never cut
    stem = _stem(
        building, model, seed, args.inputs, args.cell, occlude, args.context, args.covisible
    )
    result = Path(args.out) / f"{stem}.json"
    if result.exists():
        return f"{result.stem}: done before"
    torch.set_num_threads(args.threads)
    fold = loaded.folds[building]
    training = subset(loaded.data, loaded.origin, fold.train)
    test = subset(loaded.data, loaded.origin, [fold.test])
    config = fold_config(
        model,
        args.epochs,
        args.epoch_size,
        cell=args.cell,
        inputs=INPUTS[args.inputs],  # rgb-baseline has no switches: the same network
        occlude=occlude,
        context=training.context,
        seed=seed,
        device=args.device,
        threads=args.threads,
    )
    start = time.perf_counter()
    path = result.with_suffix(".pt")
    checkpoint = train(training, config, path, progress=False, log=lambda _line: None)
    trained = time.perf_counter() - start
    look = SecondLook(turns=args.second_look)
    probs = Validator.load(path, device=args.device, second_look=look).predict_samples(test.samples)
    right = (probs >= checkpoint.threshold) == test.labels
    spent = time.perf_counter() - start
    # Whole or absent: a job killed mid-write is run again, not read half.
    write_json_atomically(
        result,
        {
            "building": building,
            "model": model,
            "seed": seed,
            "inputs": args.inputs if model == "vgmnet" else "default",
            "cell": args.cell if model == "vgmnet" else None,
            "occlude": occlude,
            "context": args.context,
            "context_matched": bool(args.context) and training.context.matched,
            "context_covisible": bool(args.context) and training.context.covisible,
            "threshold": checkpoint.threshold,
            "p": [round(float(p), 6) for p in probs],
            "labels": test.labels.tolist(),
            "right": right.tolist(),
            "train_s": trained,
            "total_s": spent,
            "device": args.device,
        },
    )
    return (
        f"{result.stem}: accuracy {right.mean():.4f} "
        f"({trained:.0f} s training, {spent:.0f} s in all)"
    )


def _worker(args: argparse.Namespace) -> None:
    """A pool worker's start: it ends when the run that spawned it does."""
    watch_parent()
    _load(args)


def _train_all(args: argparse.Namespace) -> None:
    models = [m for m in args.models.split(",") if m]
    # In-process, the held-out buildings come with the loaded edges; a pool's workers load
    # their own, so the parent only lists the folds (their check reads every edge file once).
    names = _load(args) if args.jobs == 1 else [f.held_out for f in _folds(args)]
    jobs = [(b, m, s) for m in models for s in args.seeds for b in names]
    if args.jobs == 1:
        for job in jobs:
            print(_job(job), flush=True)
        return
    print(f"{len(jobs)} jobs on {args.jobs} processes, {args.threads} threads each", flush=True)
    # Each worker loads the edges itself.
    for line in spawned(_job, jobs, args.jobs, _worker, (args,)):
        print(line, flush=True)


def _summary(
    out: Path,
    turns: int,
    inputs: str,
    cell: float | None = None,
    occlude: float = 0.0,
    context: int = 0,
    covisible: bool = False,
) -> None:
    """Per building each seed's accuracy and, per seed pairing, the loops only one network
    judged right; then per pairing the buildings vgmnet (read with ``inputs``) is ahead on."""
    runs = [json.loads(p.read_text()) for p in sorted(out.glob("*-seed*.json"))]
    runs = [
        r
        for r in runs
        if r["model"] != "vgmnet"
        or (
            r.get("inputs", "default"),
            r.get("cell"),
            r.get("occlude", 0.0),
            r.get("context", 0),
            r.get("context_covisible", False),
        )
        == (inputs, cell, occlude, context, covisible and bool(context))
    ]
    if not runs:
        raise SystemExit(f"{out}: no fold judgements here yet; run without --summary first")
    print(f"\n# leave-one-building-out by training seed; second look over {turns}")
    print(f"# vgmnet's inputs: {inputs} {entry('vgmnet').hyper(INPUTS[inputs])}")
    print(f"# {machine()}")
    scored = {(r["building"], r["model"], r["seed"]): r for r in runs}
    right = {key: np.array(r["right"]) for key, r in scored.items()}
    seeds = {m: sorted({s for (_, mm, s) in right if mm == m}) for m in NETWORKS}
    names = sorted({b for (b, _, _) in right})
    pairings = list(itertools.product(seeds["vgmnet"], seeds["rgb-baseline"]))
    rows = [_building_row(b, right, seeds, pairings) for b in names]
    header = [
        "held out",
        *(f"{m} accuracy, seed {s}" for m in NETWORKS for s in seeds[m]),
        *(f"only vgmnet {sv} / only rgb {sr} right (p)" for sv, sr in pairings),
    ]
    print(table(header, rows))
    for m in NETWORKS:
        for s in seeds[m]:
            acc = [right[b, m, s].mean() for b in names if (b, m, s) in right]
            print(
                f"{m} seed {s}: mean accuracy {np.mean(acc):.4f}, lowest {min(acc):.4f} "
                f"(over {len(acc)} of {len(names)} buildings)"
            )
    print(
        table(["vgmnet seed", "rgb seed", *_COUNTS], [_counts(right, names, p) for p in pairings])
    )
    _ranking(scored, names, seeds)


def _ranking(
    scored: dict[tuple[str, str, int], dict[str, Any]],
    names: list[str],
    seeds: dict[str, list[int]],
) -> None:
    """Per building and draw: AUC, accuracy at the cut chosen on validation, and at the
    building's own best cut (hindsight: what a cut that transferred perfectly would give).
    Separates a model that ranks the loops worse from one whose cut landed worse."""
    from vgm_studio.model.metrics import roc_auc

    print("\n# ranking and cut: AUC / accuracy at the validation cut / at the best cut")
    header = ["held out", *(f"{m} seed {s}" for m in NETWORKS for s in seeds[m])]
    rows = []
    for b in names:
        cells = [b]
        for m in NETWORKS:
            for s in seeds[m]:
                r = scored.get((b, m, s))
                if r is None:
                    cells.append("—")
                    continue
                p, y = np.array(r["p"]), np.array(r["labels"], dtype=bool)
                best = max(float(np.mean((p >= c) == y)) for c in [*np.unique(p), np.inf])
                cells.append(f"{roc_auc(y, p):.4f} / {np.mean(r['right']):.4f} / {best:.4f}")
        rows.append(cells)
    print(table(header, rows))


_COUNTS = ["buildings", "ahead", "level", "behind", "ahead, p<0.05", "behind, p<0.05"]


def _building_row(
    b: str,
    right: dict[tuple[str, str, int], NDArray[np.bool_]],
    seeds: dict[str, list[int]],
    pairings: list[tuple[int, int]],
) -> list[str]:
    from vgm_studio.model.metrics import paired_comparison

    cells = [b]
    cells += [
        f"{right[b, m, s].mean():.4f}" if (b, m, s) in right else "—"
        for m in NETWORKS
        for s in seeds[m]
    ]
    for sv, sr in pairings:
        if (b, "vgmnet", sv) in right and (b, "rgb-baseline", sr) in right:
            c = paired_comparison(right[b, "vgmnet", sv], right[b, "rgb-baseline", sr])
            cells.append(f"{c.only_first} / {c.only_second} ({c.p_value:.3f})")
        else:
            cells.append("—")
    return cells


def _counts(
    right: dict[tuple[str, str, int], NDArray[np.bool_]], names: list[str], pairing: tuple[int, int]
) -> list[str]:
    """One seed pairing: on how many buildings vgmnet is ahead, level, behind."""
    from vgm_studio.model.metrics import paired_comparison

    sv, sr = pairing
    both = [b for b in names if (b, "vgmnet", sv) in right and (b, "rgb-baseline", sr) in right]
    counts = dict.fromkeys(_COUNTS[1:], 0)
    for b in both:
        c = paired_comparison(right[b, "vgmnet", sv], right[b, "rgb-baseline", sr])
        lead = c.only_first - c.only_second
        sure = c.p_value < 0.05
        counts["ahead"] += lead > 0
        counts["level"] += lead == 0
        counts["behind"] += lead < 0
        counts["ahead, p<0.05"] += lead > 0 and sure
        counts["behind, p<0.05"] += lead < 0 and sure
    return [str(sv), str(sr), str(len(both)), *map(str, counts.values())]


def _seeds(text: str) -> list[int]:
    try:
        return [int(s) for s in text.split(",") if s]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"not whole numbers separated by commas: {text!r}"
        ) from None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--seeds", type=_seeds, default="1,2", help="Comma-separated training seeds."
    )
    parser.add_argument("--models", default=",".join(NETWORKS), help="Comma-separated networks.")
    parser.add_argument("--buildings", default="", help="Comma-separated held-out buildings.")
    parser.add_argument("--jobs", type=int, default=1, help="Fold models trained at once.")
    parser.add_argument("--threads", type=int, default=2, help="torch threads per job.")
    parser.add_argument("--device", default="cpu", help="cpu or cuda.")
    parser.add_argument("--epochs", type=int, default=None, help="Epochs per fold model.")
    parser.add_argument("--epoch-size", type=int, default=None, help="Draws per epoch.")
    parser.add_argument("--second-look", type=int, default=4, metavar="TURNS")
    parser.add_argument(
        "--cell", type=float, default=None, help="vgmnet's cell in metres (unset: the paper's)."
    )
    parser.add_argument(
        "--occlude",
        type=float,
        default=0.0,
        help="Share of vgmnet's training draws cut by a sector (model/occlusion.py).",
    )
    parser.add_argument(
        "--context",
        type=int,
        default=0,
        help="Neighbour scans each side of a pair's scans adds on each side (model/context.py); "
        "vgmnet only: run with --models vgmnet.",
    )
    parser.add_argument(
        "--covisible",
        action="store_true",
        help="With --context: keep neighbours' points only where the pair's other scan saw.",
    )
    parser.add_argument("--out", default=str(REPO / "build" / "seeds"))
    parser.add_argument(
        "--inputs", choices=sorted(INPUTS), default="default", help="What vgmnet reads."
    )
    parser.add_argument("--summary", action="store_true", help="Only print the tables.")
    args = parser.parse_args()
    unknown = sorted(set(args.models.split(",")) - set(NETWORKS))
    if unknown:
        raise SystemExit(f"--models: unknown {', '.join(unknown)}; known: {', '.join(NETWORKS)}")
    if args.context < 0:
        raise SystemExit(f"--context: neighbour scans, 0 or more, not {args.context}")
    if args.context and "rgb-baseline" in args.models.split(",") and not args.summary:
        raise SystemExit("--context: vgmnet only; run it with --models vgmnet")
    if not 0.0 <= args.occlude <= 1.0:
        raise SystemExit(f"--occlude: a share in [0, 1], not {args.occlude}")
    if not grid_tag("vgmnet", args.cell):
        args.cell = None  # the paper's cells, named and recorded as the default's
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.summary:
        _train_all(args)
    _summary(
        out, args.second_look, args.inputs, args.cell, args.occlude, args.context, args.covisible
    )


if __name__ == "__main__":
    sys.exit(main())
