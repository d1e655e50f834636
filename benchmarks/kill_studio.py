"""Reliability: ``kill -9`` a studio while a scripted annotator labels; count what was kept.

Usage:
    python benchmarks/kill_studio.py [--rounds 10] [--seed 0] [SOURCE]

Each round starts ``vgm-studio label SOURCE --workspace W --no-trainer`` (SOURCE: the bundled
demo log unless named; the same workspace every round, so labels accumulate), opens it in
headless Chromium and presses S or F as fast as the tab answers. At a random moment 1-6 s
into the pressing the server gets SIGKILL. A label is *acknowledged* when the tab showed the
next edge after its key press: the studio commits a label before it moves the tab on. After
each kill the store is read back: every acknowledged label must be there with its value, and
``PRAGMA integrity_check`` must say ok. Prints one row per round and the totals.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import sqlite3
import tempfile
import threading
from pathlib import Path

from _common import REPO, machine, table
from studio_browser import StudioPage, chromium, free_port, studio_process

DEMO_LOG = REPO / "datasets" / "demo-seed0.log"


def _stored(workspace: Path) -> tuple[dict[str, str], str]:
    """The store's labels (edge → label) and its integrity check, read after the kill."""
    db = sqlite3.connect(workspace / "labels.sqlite")
    try:
        labels = dict(db.execute("SELECT edge_id, label FROM labels").fetchall())
        integrity = db.execute("PRAGMA integrity_check").fetchone()[0]
    finally:
        db.close()
    return labels, integrity


def one_round(source: Path, workspace: Path, browser: object, delay: float, rng: random.Random):
    """Labels until the server is killed ``delay`` s in; returns (acknowledged, lost, ok)."""
    port = free_port()
    args = ["label", str(source), "--workspace", str(workspace), "--no-trainer", "--no-model"]
    acknowledged: dict[str, str] = {}
    with studio_process([*args, "--annotator", "bot"], port, timeout=600) as proc:
        tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}", timeout=60.0)  # type: ignore[attr-defined]
        tab.timeout_ms = 10_000  # a press after the kill is given up on after this
        killer = threading.Timer(delay, os.kill, (proc.pid, signal.SIGKILL))
        killer.start()
        while True:
            edge = tab.edge_id()
            label = rng.choice(("success", "failure"))
            try:
                tab.press("s" if label == "success" else "f")
                shown = tab.edge_id()
            except Exception:  # the server is gone: this press was never acknowledged
                break
            # Acknowledged only by a next edge on screen (a dropped connection also changes
            # the page, and then shows none).
            if edge and shown and shown != edge:
                acknowledged[edge] = label
            elif not shown:
                break
        killer.join()
        proc.wait(timeout=30)
        tab.page.close()
    stored, integrity = _stored(workspace)
    lost = sum(stored.get(edge) != label for edge, label in acknowledged.items())
    return len(acknowledged), lost, integrity


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("source", nargs="?", type=Path, default=DEMO_LOG)
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    rows, total_ack, total_lost = [], 0, 0
    with tempfile.TemporaryDirectory() as tmp, chromium(viewport=(1280, 720)) as browser:
        workspace = Path(tmp) / "ws"
        for k in range(args.rounds):
            delay = rng.uniform(1.0, 6.0)
            ack, lost, integrity = one_round(args.source, workspace, browser, delay, rng)
            total_ack, total_lost = total_ack + ack, total_lost + lost
            rows.append([str(k + 1), f"{delay:.1f} s", str(ack), str(lost), integrity])
        stored = len(_stored(workspace)[0])
    print(f"machine: {machine()}")
    print(table(["round", "killed after", "acknowledged", "lost", "integrity"], rows))
    print(f"total: {total_ack} acknowledged labels, {total_lost} lost, {stored} stored")


if __name__ == "__main__":
    main()
