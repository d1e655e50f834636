"""The background trainer's proof: a scripted annotator labels in the browser, the trainer learns.

Usage:
    python benchmarks/bench_trainer.py [--labels 300] [--pace 1.0] [--preset loop]
                                       [--plot docs/images/trainer-curves.png] [--results R.json]
    python benchmarks/bench_trainer.py replot R.json 300 OUT.png

For each labeling order (log order, then "most uncertain first"), from an empty workspace and
no model:

1. The workspace holds the loop candidates of a simulated corridor log (``--preset``, seed 1:
   the benchmark protocol's loop pairs, labelled from the simulator's ground truth).
2. Three processes, as ``vgm-studio label`` with its trainer will run them: the app (the
   studio, with a ``PromotionWatcher`` that refreshes p(success) when a version is promoted),
   the trainer (``python -m vgm_studio.trainer``, one thread, niced), and headless Chromium.
3. The annotator presses S or F (the edge's reference label; D skips an ambiguous edge), one
   label every ``--pace`` seconds at most. In the uncertainty run it picks the queue again
   after each promotion, so that the order follows the newest predictions.
4. After ``--labels`` labels it waits for the trainer to learn from the last of them, then
   scores every version on an independent log of the same world (seed 2, its loop
   candidates): the trainer's own held-out split is small and, in the uncertainty run, made of
   the hardest edges, so it cannot compare the two orders.

Prints one table per order, the labels and training time each order needed to reach the target
accuracy, the label latency with the trainer running, and draws both curves to ``--plot``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from _common import machine, pin_to_cores, table

if TYPE_CHECKING:
    from vgm_studio.labels import LabelStore
    from vgm_studio.model.training import LabelledSet

TARGET = 0.90
ORDERS = {"log": "unlabelled first", "uncertain": "most uncertain first"}  # queue names
NAMES = {"log": "log order", "uncertain": "most uncertain first"}
COLOURS = {"log": (200, 120, 30), "uncertain": (40, 110, 230)}  # BGR


def make_edges(preset: str, seed: int, folder: Path) -> Path:
    """A simulated log of ``preset`` and its loop candidates, labelled from ground truth."""
    from vgm_studio.datasets import open_log
    from vgm_studio.matching.candidates import CandidateConfig, make_candidates
    from vgm_studio.matching.edges import write_edges
    from vgm_studio.matching.matcher import ScanMatcher
    from vgm_studio.simulation.simulate import SimConfig, simulate

    folder.mkdir(parents=True, exist_ok=True)
    log = open_log(simulate(SimConfig(preset=preset, seed=seed), folder))
    edges = make_candidates(
        log, ScanMatcher(), CandidateConfig(sequential=False, seed=seed), progress=False
    )
    path = folder / f"{preset}-seed{seed}-loops.jsonl"
    write_edges(path, edges)
    return path


# -- the app process ----------------------------------------------------------------------


def serve(workspace: Path, port: int) -> None:
    """The app: the studio plus what the trainer needs from it (refresh on promotion)."""
    from vgm_studio.labels import LabelStore
    from vgm_studio.studio.app import Studio, StudioConfig
    from vgm_studio.trainer import PromotionWatcher

    store = LabelStore(workspace, create=False)
    studio = Studio(store, StudioConfig(port=port, annotator="bench"))
    studio.start()
    watcher = PromotionWatcher(store, lambda _name: studio.refresh_predictions())
    watcher.start()
    print(f"VGM Studio: {store.count_edges()} edges at {studio.url}", flush=True)
    try:
        while True:
            time.sleep(3600)
    finally:
        watcher.stop()
        studio.stop()


@contextmanager
def process(cmd: list[str], ready: str | None, log: Path) -> Iterator[subprocess.Popen[str]]:
    """Runs ``cmd`` (until it prints a line starting with ``ready``); stops it afterwards."""
    with log.open("w") as out:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert proc.stdout is not None
        stream = proc.stdout
        started = threading.Event()

        def copy() -> None:  # drain the pipe all along, or a chatty process would block on it
            for line in stream:
                out.write(line)
                out.flush()
                if ready and line.startswith(ready):
                    started.set()
            started.set()

        threading.Thread(target=copy, daemon=True).start()
        try:
            if ready:
                started.wait(300)
                if proc.poll() is not None:
                    raise RuntimeError(f"{' '.join(cmd[1:3])} exited: see {log}")
            yield proc
        finally:
            proc.terminate()
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


# -- one run -----------------------------------------------------------------------------


@dataclass
class Version:
    """One registered version as the benchmark saw it."""

    name: str
    labels: int
    wall: float
    train_seconds: float
    held_out: float
    held_out_n: int
    promoted: bool
    test: dict[str, float] = field(default_factory=dict)


@dataclass
class Run:
    order: str
    versions: list[Version]
    latencies: list[float]
    label_seconds: float


def run_order(order: str, edges: Path, work: Path, args: argparse.Namespace) -> Run:
    from studio_browser import StudioPage, chromium, free_port

    from vgm_studio.datasets import ReadOptions
    from vgm_studio.labels import LabelStore
    from vgm_studio.trainer import registry
    from vgm_studio.workspace import fill_workspace

    ws = work / f"ws-{order}"
    store = LabelStore(ws)
    fill_workspace(store, edges, None, ReadOptions())
    reference = store.reference_labels()
    port = free_port()
    app = [sys.executable, __file__, "serve", str(ws), str(port)]
    trainer = [
        sys.executable,
        "-m",
        "vgm_studio.trainer",
        "--workspace",
        str(ws),
        "--retrain-every",
        str(args.retrain_every),
    ]
    latencies: list[float] = []
    with (
        process(app, "VGM Studio:", work / f"app-{order}.log"),
        process(trainer, None, work / f"trainer-{order}.log"),
        chromium(viewport=(1280, 720)) as browser,
    ):
        start, wall_start = time.monotonic(), time.time()
        tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
        tab.choose_queue(ORDERS[order])
        shown = store.predictions().model
        labels = 0
        while labels < args.labels:
            t0 = time.monotonic()
            if order == "uncertain" and store.predictions().model != shown:
                # Pick the queue again: it is ordered by the predictions when chosen.
                shown = store.predictions().model
                tab.choose_queue("unlabelled first")
                tab.choose_queue(ORDERS[order])
            label = reference.get(tab.edge_id() or "")
            if label in ("success", "failure"):
                latencies.append(tab.press("s" if label == "success" else "f"))
                labels += 1
            else:
                tab.press("d")
            time.sleep(max(0.0, args.pace - (time.monotonic() - t0)))
        label_seconds = time.monotonic() - start
        print(f"  {order}: {labels} labels in {label_seconds:.0f} s; waiting for the trainer")
        # "Train now" once the labeling is done, so that the last version has seen every label.
        registry.request_training(store)
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            status = registry.trainer_status(store)
            if not status.pending_request and status.state == "idle":
                break
            time.sleep(1.0)
    versions = []
    trained = 0.0
    for m in registry.list_models(store):
        trained += m.seconds
        made = datetime.fromisoformat(m.created_at).timestamp()
        versions.append(
            Version(
                name=m.name,
                labels=m.labels_seen,
                wall=made - wall_start,
                train_seconds=trained,
                held_out=float(m.metrics.get("accuracy", math.nan)),
                held_out_n=int(m.metrics.get("n", 0)),
                promoted=m.promoted,
            )
        )
    score(versions, store, args.test)
    store.close()
    return Run(order, versions, latencies, label_seconds)


def score(versions: list[Version], store: LabelStore, test: LabelledSet) -> None:
    """Each version's figures on the independent test log."""
    from vgm_studio.model.metrics import binary_metrics
    from vgm_studio.model.validator import Validator
    from vgm_studio.trainer import registry

    for v in versions:
        record = registry.get_model(store, int(v.name[1:]))
        assert record is not None
        validator = Validator.load(record.path, device="cpu")
        p = validator.predict_samples(test.samples)
        v.test = binary_metrics(test.labels, p, validator.threshold)


# -- report --------------------------------------------------------------------------------


def first_reaching(run: Run, accuracy: float) -> Version | None:
    return next((v for v in run.versions if v.promoted and v.test["accuracy"] >= accuracy), None)


def report(runs: list[Run], args: argparse.Namespace, test_counts: str) -> None:
    print(f"machine: {machine()}")
    print(
        f"world: {args.preset} (seed 1 labelled, seed 2 tested: {test_counts}); "
        f"a version every {args.retrain_every} labels, from scratch; pace {args.pace} s/label"
    )
    for run in runs:
        print(f"\n{NAMES[run.order]} (queue: {ORDERS[run.order]})")
        rows = [
            [
                v.name,
                str(v.labels),
                f"{v.wall:.0f}",
                f"{v.train_seconds:.0f}",
                f"{v.held_out:.3f} ({v.held_out_n})",
                f"{v.test['accuracy']:.3f}",
                f"{v.test['f1']:.3f}",
                f"{v.test['auc']:.3f}",
                "yes" if v.promoted else "no",
            ]
            for v in run.versions
        ]
        print(
            table(
                [
                    "version",
                    "labels",
                    "wall s",
                    "train s (sum)",
                    "held-out acc (n)",
                    "test acc",
                    "test F1",
                    "test AUC",
                    "promoted",
                ],
                rows,
            )
        )
    print()
    rows = []
    for goal in (0.80, 0.85, TARGET):
        row = [f"test accuracy ≥ {goal:.2f}"]
        for run in runs:
            v = first_reaching(run, goal)
            row.append(f"{v.labels} labels, {v.train_seconds:.0f} s" if v else "not reached")
        rows.append(row)
    best = ["best promoted test accuracy"]
    for run in runs:
        promoted = [v.test["accuracy"] for v in run.versions if v.promoted]
        best.append(f"{max(promoted):.3f}" if promoted else "none")
    rows.append(best)
    lat = ["label → next edge p50 / p95 (trainer on)"]
    for run in runs:
        ms = sorted(1000 * t for t in run.latencies)
        lat.append(f"{ms[len(ms) // 2]:.0f} / {ms[min(len(ms) - 1, round(0.95 * len(ms)))]:.0f} ms")
    rows.append(lat)
    print(table(["", *(NAMES[r.order] for r in runs)], rows))


def plot(runs: list[Run], path: Path, labels: int) -> None:
    """Test accuracy of each promoted version against labels, drawn with opencv."""
    w, h, left, right, top, bottom = 900, 520, 80, 30, 50, 70
    img = np.full((h, w, 3), 255, np.uint8)
    lo, hi = 0.4, 1.0

    def xy(n: float, acc: float) -> tuple[int, int]:
        x = left + (w - left - right) * n / labels
        y = top + (h - top - bottom) * (hi - acc) / (hi - lo)
        return round(x), round(y)

    font = cv2.FONT_HERSHEY_SIMPLEX
    for acc in np.arange(lo, hi + 1e-9, 0.1):
        cv2.line(img, xy(0, acc), xy(labels, acc), (225, 225, 225), 1)
        cv2.putText(img, f"{acc:.1f}", (left - 45, xy(0, acc)[1] + 5), font, 0.5, (0, 0, 0), 1)
    for n in range(0, labels + 1, 50 if labels >= 150 else 10):
        cv2.putText(img, str(n), (xy(n, lo)[0] - 12, h - bottom + 22), font, 0.5, (0, 0, 0), 1)
    cv2.line(img, xy(0, TARGET), xy(labels, TARGET), (60, 60, 200), 1, cv2.LINE_AA)
    cv2.putText(
        img,
        "target 0.90",
        (xy(labels, TARGET)[0] - 110, xy(0, TARGET)[1] - 8),
        font,
        0.5,
        (60, 60, 200),
        1,
        cv2.LINE_AA,
    )
    cv2.rectangle(img, xy(0, hi), xy(labels, lo), (0, 0, 0), 1)
    for k, run in enumerate(runs):
        points = [xy(v.labels, v.test["accuracy"]) for v in run.versions if v.promoted]
        colour = COLOURS[run.order]
        if len(points) > 1:
            cv2.polylines(img, [np.array(points, np.int32)], False, colour, 2, cv2.LINE_AA)
        for p in points:
            cv2.circle(img, p, 5, colour, -1, cv2.LINE_AA)
        cv2.putText(
            img,
            NAMES[run.order],
            (left + 20, top + 25 + 22 * k),
            font,
            0.6,
            colour,
            2,
            cv2.LINE_AA,
        )
    cv2.putText(img, "labels", (w // 2 - 30, h - 20), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(
        img,
        "accuracy of each promoted version on an independent log",
        (left, 30),
        font,
        0.6,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def save(runs: list[Run], path: Path) -> None:
    """The curves' figures as JSON, so the plot can be redrawn without labeling again."""
    body = [
        {
            "order": r.order,
            "versions": [asdict(v) for v in r.versions],
            "latencies": r.latencies,
            "label_seconds": r.label_seconds,
        }
        for r in runs
    ]
    path.write_text(json.dumps(body, indent=1) + "\n")


def load(path: Path) -> list[Run]:
    runs = []
    for r in json.loads(path.read_text()):
        versions = [Version(**v) for v in r["versions"]]
        runs.append(Run(r["order"], versions, r["latencies"], r["label_seconds"]))
    return runs


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "serve":
        serve(Path(sys.argv[2]), int(sys.argv[3]))
        return
    if len(sys.argv) == 5 and sys.argv[1] == "replot":  # replot RESULTS.json LABELS OUT.png
        plot(load(Path(sys.argv[2])), Path(sys.argv[4]), int(sys.argv[3]))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--labels", type=int, default=300)
    parser.add_argument("--pace", type=float, default=1.0, help="Seconds per label at least.")
    parser.add_argument("--retrain-every", type=int, default=25)
    parser.add_argument("--preset", default="loop", help="Simulated corridor world.")
    parser.add_argument("--orders", default="log,uncertain")
    # No default: the README's picture is tracked and is replaced only when asked for.
    parser.add_argument("--plot", type=Path, help="Draw the curves here (PNG).")
    parser.add_argument("--keep", type=Path, help="Keep the workspaces and logs here.")
    parser.add_argument("--results", type=Path, help="Also write the figures as JSON here.")
    args = parser.parse_args()
    pin_to_cores(2)
    from vgm_studio.model.training import read_labelled

    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        edges = make_edges(args.preset, 1, work / "train")
        args.test = read_labelled([make_edges(args.preset, 2, work / "test")], progress=False)
        y = args.test.labels
        counts = f"{len(y)} edges, {int(y.sum())} success / {int((~y).sum())} failure"
        runs = []
        for order in args.orders.split(","):
            print(f"labeling in {ORDERS[order]} order …", flush=True)
            runs.append(run_order(order, edges, work, args))
        report(runs, args, counts)
        if args.results:
            save(runs, args.results)
        if args.plot:
            plot(runs, args.plot, args.labels)
            print(f"\nwrote {args.plot}")


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main()
