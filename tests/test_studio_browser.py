"""The studio in a real headless Chromium against a real server process and SQLite store."""

from __future__ import annotations

import os
import signal
import sqlite3
from pathlib import Path

import pytest

from benchmarks.studio_browser import StudioPage, chromium, chromium_path, free_port, studio_process
from vgm_studio.labels import LabelStore
from vgm_studio.matching.edges import read_edges

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", autouse=True)
def _needs_chromium():
    if chromium_path() is None:
        reason = "Debian chromium is not installed (.ci/run installs it)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"CI=true but {reason}")
        pytest.skip(reason)


def _labels(workspace: Path) -> list[tuple[str, str, str]]:
    db = sqlite3.connect(workspace / "labels.sqlite")
    try:
        return db.execute(
            "SELECT edge_id, annotator, label FROM labels ORDER BY edge_id"
        ).fetchall()
    finally:
        db.close()


def _label_args(edges: Path, workspace: Path) -> list[str]:
    return [
        *("label", str(edges), "--workspace", str(workspace)),
        *("--no-model", "--no-trainer", "--annotator", "ana"),
    ]


def test_label_click_hotkey_undo_queue_and_reload(office_edges, tmp_path, artifacts):
    ids = [e.edge_id for e in read_edges(office_edges)]
    ws = tmp_path / "ws"
    port = free_port()
    with studio_process(_label_args(office_edges, ws), port), chromium() as browser:
        tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
        assert tab.position() == (1, len(ids)) and tab.edge_id() == ids[0]
        tab.screenshot(artifacts / "studio-first-edge.png")

        tab.click("Success")
        assert tab.edge_id() == ids[1]
        tab.press("f")
        assert tab.edge_id() == ids[2]
        assert sorted(_labels(ws)) == sorted(
            [(ids[0], "ana", "success"), (ids[1], "ana", "failure")]
        )
        assert tab.labelled() == 2

        tab.press("z")  # undo the failure: back to that edge, label gone, history kept
        assert tab.edge_id() == ids[1]
        assert _labels(ws) == [(ids[0], "ana", "success")]
        db = sqlite3.connect(ws / "labels.sqlite")
        assert [r[0] for r in db.execute("SELECT action FROM events ORDER BY id")] == [
            "label",
            "label",
            "undo",
        ]
        db.close()

        tab.choose_queue("in log order")
        assert tab.position() == (1, len(ids)) and tab.edge_id() == ids[0]
        tab.press("e")
        tab.press("e")
        assert tab.position() == (3, len(ids))
        tab.press("q")
        assert tab.edge_id() == ids[1]
        tab.choose_queue("conflicts")
        assert tab.empty()

        tab.page.reload()
        again = StudioPage(tab.page, f"http://127.0.0.1:{port}")
        # A new tab starts in "unlabelled first": the first edge nobody labelled.
        assert again.edge_id() == ids[1] and again.labelled() == 1
        again.screenshot(artifacts / "studio-after-reload.png")


def test_two_tabs_are_never_handed_the_same_edge(office_edges, tmp_path):
    ws = tmp_path / "ws"
    port = free_port()
    with studio_process(_label_args(office_edges, ws), port), chromium() as browser:
        url = f"http://127.0.0.1:{port}"
        first = StudioPage(browser.new_page(), url)
        second = StudioPage(browser.new_page(), url)
        assert first.edge_id() != second.edge_id()
        seen = [first.edge_id(), second.edge_id()]
        for _ in range(3):
            first.press("s")
            second.press("f")
            seen += [first.edge_id(), second.edge_id()]
        assert len(set(seen)) == len(seen)
        labels = _labels(ws)
        assert len(labels) == 6 and len({e for e, _, _ in labels}) == 6


def test_labels_survive_a_kill(office_edges, tmp_path):
    ws = tmp_path / "ws"
    port = free_port()
    with chromium() as browser:
        with studio_process(_label_args(office_edges, ws), port) as proc:
            tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
            shown = []
            for key in "sfsfs":
                shown.append(tab.edge_id())
                tab.press(key)
            # No shutdown, no flush: the process dies between two clicks.
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        assert sorted(e for e, _, _ in _labels(ws)) == sorted(shown)
        port = free_port()
        with studio_process(_label_args(office_edges, ws), port):
            tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
            assert tab.labelled() == 5
            assert tab.edge_id() not in shown


def test_the_trainer_learns_from_labels_and_the_tab_shows_its_model(office_edges, tmp_path):
    edges = read_edges(office_edges)
    ws = tmp_path / "ws"
    port = free_port()
    args = [*_label_args(office_edges, ws), "--retrain-every", "12"]
    args.remove("--no-trainer")
    with studio_process(args, port), chromium() as browser:
        tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
        for i in range(24):
            # Both classes, whatever the edges are: this checks the loop, not the labels.
            tab.press("sf"[i % 2])
        tab.wait_for(lambda: "model v1" in tab.trainer(), 120)
        tab.wait_for(
            lambda: (
                "p(success)" in tab.page.inner_text("body")
                and "no model" not in tab.page.inner_text("body")
            ),
            30,
        )
        preds = LabelStore(ws).predictions()
        assert preds.model == "v1" and len(preds.p) == len(edges)
        tab.screenshot(tmp_path / "trained.png")
