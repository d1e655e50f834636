"""Studio speed in a real browser: label click → next edge pushed, and demo start-up.

Usage:
    python benchmarks/bench_studio.py [--edges 200]

1. ``vgm-studio label intel.gfs.log`` (candidates made on first open, the bundled model's
   predictions) served to headless Chromium; an annotator presses S or F (the edge's reference
   label) 200 times in "most uncertain first" order, which mixes loop and sequential edges.
   Each latency is from the key press until the tab shows the next edge: the panel's position
   line is sent after the scene (VGM image, scans, poses), so when it changes the whole edge
   has arrived.
2. ``vgm-studio demo``: seconds from the process start until it serves, with a fresh workspace
   (candidates made) and with the workspace kept from the first run.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from _common import REPO, datasets_dir, machine, table

from vgm_studio.labels import LabelStore
from vgm_studio.studio.browser import StudioPage, chromium, free_port, studio_process


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def label_latency(count: int, work: Path) -> list[float]:
    log = datasets_dir() / "intel" / "intel.gfs.log"
    ws = work / "intel"
    port = free_port()
    latencies = []
    with studio_process(["label", str(log), "--workspace", str(ws)], port, timeout=600):
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
                latencies.append(tab.press(key))
        assert len(store.labels()) == count, "every press must have stored a label"
    return latencies


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
                with chromium(viewport=(1280, 720)) as browser:
                    tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
                    tab.choose_queue("most uncertain first")
                    time.sleep(2)  # let the software renderer finish the frame
                    tab.screenshot(screenshot)
    return times[0], times[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--edges", type=int, default=200)
    parser.add_argument(
        "--screenshot", type=Path, help="Also save the demo's first edge, e.g. for README."
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(
        dir=REPO / "build" if (REPO / "build").is_dir() else None
    ) as tmp:
        work = Path(tmp)
        latencies = label_latency(args.edges, work)
        cold, warm = demo_startup(work, args.screenshot)
    ms = [1000 * t for t in latencies]
    print(f"machine: {machine()}")
    print(
        table(
            ["measure", "value", "target"],
            [
                [
                    f"label → next edge, p50 ({len(ms)} edges, Intel)",
                    f"{statistics.median(ms):.0f} ms",
                    "",
                ],
                ["label → next edge, p95", f"{_percentile(ms, 0.95):.0f} ms", "≤ 150 ms"],
                ["label → next edge, max", f"{max(ms):.0f} ms", ""],
                ["`vgm-studio demo` ready, fresh workspace", f"{cold:.1f} s", "≤ 10 s"],
                ["`vgm-studio demo` ready, workspace kept", f"{warm:.1f} s", ""],
            ],
        )
    )


if __name__ == "__main__":
    main()
