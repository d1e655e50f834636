"""Studio speed in a real browser: label click → next edge pushed, and demo start-up.

Usage:
    python benchmarks/bench_studio.py [--edges 200]

1. ``vgm-studio label intel.gfs.log`` (candidates made on first open, the bundled model's
   predictions) served to headless Chromium; an annotator presses S or F (the edge's reference
   label) 200 times in "most uncertain first" order, which mixes loop and sequential edges.
   Each latency is from the key press until the tab shows the next edge: the panel's position
   line is sent after the scene (VGM image, scans, poses), so when it changes the whole edge
   has arrived.
   Twice: with ``--no-trainer``, then with the background trainer (retraining every 25 labels),
   and the presses made while it was training are also reported alone.
2. Deep links: ``?edge=ID`` opened in a new tab, seconds from the page load until the tab
   shows that edge (polled in the page at every frame), for edges spread over the queue.
3. ``vgm-studio demo``: seconds from the process start until it serves, with a fresh workspace
   (candidates made) and with the workspace kept from the first run.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from _common import REPO, datasets_dir, machine, table
from studio_browser import StudioPage, chromium, free_port, studio_process

from vgm_studio.labels import LabelStore
from vgm_studio.trainer import trainer_status


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def label_latency(count: int, work: Path, trainer: bool) -> tuple[list[float], list[bool]]:
    """Seconds from each press to the next edge, and whether the trainer was training then."""
    log = datasets_dir() / "intel" / "intel.gfs.log"
    ws = work / ("intel-trainer" if trainer else "intel")
    port = free_port()
    latencies: list[float] = []
    training: list[bool] = []
    args = ["label", str(log), "--workspace", str(ws)]
    if not trainer:
        args.append("--no-trainer")
    with studio_process(args, port, timeout=600):
        store = LabelStore(ws)
        reference = store.reference_labels()
        # The model's predictions are made in the background; wait so the queue uses them.
        deadline = time.monotonic() + 120
        while not store.predictions().p and time.monotonic() < deadline:
            time.sleep(0.5)
        # A laptop-sized window: without a GPU the browser's cost grows with its pixels.
        with chromium(viewport=(1280, 720)) as browser:
            tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
            tab.choose_queue("most uncertain first")
            for _ in range(count):
                edge = tab.edge_id()
                key = "f" if reference.get(edge or "") == "failure" else "s"
                training.append(trainer and trainer_status(store).state == "training")
                latencies.append(tab.press(key))
        assert len(store.labels()) == count, "every press must have stored a label"
    return latencies, training


def deep_links(count: int, work: Path) -> list[float]:
    """Seconds from loading ``?edge=ID`` until the tab shows that edge, ``count`` edges."""
    ws = work / "intel"
    log = datasets_dir() / "intel" / "intel.gfs.log"
    port = free_port()
    seconds = []
    with studio_process(["label", str(log), "--workspace", str(ws), "--no-trainer"], port):
        edges = sorted(LabelStore(ws).reference_labels())
        targets = edges[:: max(1, len(edges) // count)][:count]
        with chromium(viewport=(1280, 720)) as browser:
            for edge in targets:
                page = browser.new_page()
                page.goto(f"http://127.0.0.1:{port}/?edge={edge}")
                loaded = time.perf_counter()
                page.wait_for_function(
                    "id => [...document.querySelectorAll('code')]"
                    ".some(c => c.innerText.trim() === id)",
                    arg=edge,
                    polling="raf",
                    timeout=30_000,
                )
                seconds.append(time.perf_counter() - loaded)
                page.close()
    return seconds


def readme_picture(port: int, path: Path) -> None:
    """The README's picture: the first edge "most uncertain first", the panel from its top."""
    with chromium(viewport=(1400, 900)) as browser:
        tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
        tab.choose_queue("most uncertain first")
        # Picking a queue scrolls the panel down to the dropdown; the picture shows its top.
        tab.page.mouse.move(1200, 300)
        tab.page.mouse.wheel(0, -5000)
        tab.page.mouse.move(300, 300)
        time.sleep(2)  # let the software renderer finish the frame
        tab.screenshot(path)


def demo_startup(work: Path, screenshot: Path | None = None) -> tuple[float, float]:
    """Seconds until ``vgm-studio demo`` serves: fresh, then kept workspace (+ README picture)."""
    times = []
    for run in range(2):
        start = time.perf_counter()
        port = free_port()
        with studio_process(["demo", "--workspace", str(work / "demo")], port):
            times.append(time.perf_counter() - start)
            if screenshot is not None and run == 1:
                store = LabelStore(work / "demo")
                while not store.predictions().p:  # made in the background after start
                    time.sleep(0.5)
                readme_picture(port, screenshot)
    return times[0], times[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--edges", type=int, default=200)
    parser.add_argument("--links", type=int, default=20, help="Deep links opened.")
    parser.add_argument("--links-only", action="store_true", help="Measure the deep links alone.")
    parser.add_argument(
        "--screenshot", type=Path, help="Also save the demo's first edge, e.g. for README."
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(
        dir=REPO / "build" if (REPO / "build").is_dir() else None
    ) as tmp:
        work = Path(tmp)
        if args.links_only:
            _print_links(deep_links(args.links, work))
            return
        alone, _ = label_latency(args.edges, work, trainer=False)
        links = deep_links(args.links, work)
        beside, training = label_latency(args.edges, work, trainer=True)
        cold, warm = demo_startup(work, args.screenshot)
    during = [t for t, busy in zip(beside, training, strict=True) if busy]
    rows = []
    for name, seconds in (
        ("no trainer", alone),
        ("trainer on", beside),
        ("trainer on, presses while it trains", during),
    ):
        if not seconds:
            rows.append([f"label → next edge, {name}", "no such presses", ""])
            continue
        ms = [1000 * t for t in seconds]
        rows.append(
            [
                f"label → next edge, {name} ({len(ms)} presses)",
                f"{statistics.median(ms):.0f} / {_percentile(ms, 0.95):.0f} / {max(ms):.0f} ms",
                "p95 ≤ 150 ms",
            ]
        )
    print(f"machine: {machine()}")
    print(
        table(
            ["measure (Intel, most uncertain first)", "p50 / p95 / max", "target"],
            [
                *rows,
                _link_row(links),
                ["`vgm-studio demo` ready, fresh workspace", f"{cold:.1f} s", "≤ 10 s"],
                ["`vgm-studio demo` ready, workspace kept", f"{warm:.1f} s", ""],
            ],
        )
    )


def _link_row(seconds: list[float]) -> list[str]:
    return [
        f"deep link `?edge=ID` → that edge shown ({len(seconds)} links)",
        f"{statistics.median(seconds):.2f} / {_percentile(seconds, 0.95):.2f} / "
        f"{max(seconds):.2f} s",
        "≤ 2 s",
    ]


def _print_links(seconds: list[float]) -> None:
    print(f"machine: {machine()}")
    print(table(["measure (Intel)", "p50 / p95 / max", "target"], [_link_row(seconds)]))


if __name__ == "__main__":
    main()
