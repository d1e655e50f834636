"""A SLAM run's decisions in the studio: the loops file carries them, the panel and the run's
queues show them, and a link opens one edge (in a real headless Chromium)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from vgm_studio.matching.edges import Edge, read_edges
from vgm_studio.studio.decisions import decision_rows, run_header
from vgm_studio.studio.gate import _page
from vgm_studio.studio.links import LINK_JS, Link, link_url, opening, parse
from vgm_studio.studio.queues import Queue, RunDecisions, Snapshot, order


def _edge(edge_id: str, slam: dict | None, label: str | None = None) -> Edge:
    match = {} if slam is None else {"slam": slam}
    return Edge(edge_id, "x.log", "0" * 64, 0, 5, 0.0, 1.0, "loop", [0, 0, 0], [1, 0, 0], match,
                [1, 0, 0], label)  # fmt: skip


def test_the_runs_queues_sort_by_its_decisions_and_the_labels():
    ids = ["a", "b", "c", "d", "e", "f"]
    run = RunDecisions(
        kept={"a": True, "b": True, "c": False, "d": False, "e": True},
        reference={"a": "failure", "b": "failure", "c": "success", "d": "failure"},
        off={"a": 0.4, "b": 6.0},
    )
    # An annotator's label wins over the reference: "e" is a false loop by her word, "d" a
    # right one the run lost.
    labels = {"e": {"ana": "failure"}, "d": {"ana": "success", "bo": "success"}}
    snap = Snapshot(ids, labels, run=run)
    assert order(Queue.kept, snap) == ["a", "b", "e"]
    assert order(Queue.rejected, snap) == ["c", "d"]
    # The loop furthest off its reference first; one without a reference last.
    assert order(Queue.kept_failure, snap) == ["b", "a", "e"]
    assert order(Queue.rejected_success, snap) == ["c", "d"]
    header = run_header(snap)
    assert "3 kept · 2 rejected · 3 kept, labelled failure · 2 rejected, labelled success" in header
    assert run_header(Snapshot(ids)) == ""


def test_the_panel_shows_source_p_cut_group_residual_and_escapes_the_file():
    slam = {
        "source": "place",
        "p_success": 0.91,
        "cut": 0.8,
        "validated": True,
        "kept": True,
        "consistency": "kept",
        "group": {"id": 7, "checked": 5, "kept": 4},
        "injected": False,
        "residual": {"metres": 0.123, "degrees": 1.5},
    }
    text = " | ".join(f"{k}: {v}" for k, v in decision_rows(_edge("a", slam)))
    assert "place recognition" in text
    assert "p 0.91 ≥ cut 0.80: passed" in text
    assert "kept in group 7 (5 loops checked, 4 kept)" in text
    assert "**kept** in the graph" in text and "12.3 cm, 1.5°" in text
    hostile = {**slam, "source": "<img src=x onerror=alert(1)>", "p_success": "high"}
    text = " | ".join(v for _, v in decision_rows(_edge("a", hostile)))
    assert "<img" not in text and "&lt;img" in text and "p –" in text
    assert decision_rows(_edge("a", None)) == []


def test_a_link_names_an_edge_and_a_queue():
    assert parse("/tok?edge=ab%2Fc&queue=kept-failure") == Link("ab/c", Queue.kept_failure)
    assert parse("/?edge=x&queue=nonsense") == Link("x", None, "nonsense")
    assert parse("/") == Link()
    url = link_url("http://localhost:8080/", "ab/c", Queue.kept_failure)
    assert url == "http://localhost:8080/?edge=ab%2Fc&queue=kept-failure"
    assert parse(url.removeprefix("http://localhost:8080")) == Link("ab/c", Queue.kept_failure)
    # The hook runs before viser's own script, which makes the worker it patches.
    page = _page()[0].decode()
    assert page.index(LINK_JS) < page.index("<script", page.index(LINK_JS) + len(LINK_JS))
    snap = Snapshot(["a", "b", "c"], run=RunDecisions(kept={"a": True, "b": False, "c": True}))
    queues = list(Queue)
    start = opening(Link("c", Queue.kept), Queue.unlabelled, snap, queues)
    assert (start.queue, start.order, start.index, start.note) == (Queue.kept, ["a", "c"], 1, "")
    start = opening(Link("b", Queue.kept), Queue.unlabelled, snap, queues)
    assert start.queue is Queue.log and start.index == 1 and "not in" in start.note
    start = opening(Link("zz"), Queue.unlabelled, snap, queues)
    assert start.index is None and "No such edge" in start.note


@pytest.fixture(scope="module")
def run_loops(tmp_path_factory) -> Path:
    """A run that kept false loops: injected ones and what they bent, no validator, no check.

    Place recognition and the final sweep are off, so the loops are the window search's
    (right while the graph is) and the injected ones; the loops file holds both.
    """
    from vgm_studio.datasets import open_log
    from vgm_studio.matching.edges import write_edges
    from vgm_studio.simulation.simulate import SimConfig, simulate
    from vgm_studio.slam.config import (
        ConsistencyConfig,
        FrontEndConfig,
        SlamConfig,
        ValidationConfig,
    )
    from vgm_studio.slam.loop_edges import loop_edges
    from vgm_studio.slam.pipeline import run_slam

    folder = tmp_path_factory.mktemp("run")
    log = open_log(
        simulate(SimConfig(preset="office", seed=1, num_beams=181, scan_spacing=0.2), folder)
    )
    front = FrontEndConfig(place_candidates=0, place_candidates_drifted=0, final_sweep=False,
                           false_loops=6, seed=0)  # fmt: skip
    config = SlamConfig(front_end=front, validation=ValidationConfig(validator="none"),
                        consistency=ConsistencyConfig(enabled=False))  # fmt: skip
    result = run_slam(log, config, progress=False)
    path = folder / "loops.jsonl"
    write_edges(path, loop_edges(log, result, {}, injected=True))
    return path


@pytest.mark.slow
@pytest.mark.usefixtures("needs_chromium")
def test_the_kept_false_loop_comes_first_with_the_runs_decisions_and_a_link_opens_an_edge(
    run_loops, tmp_path, artifacts
):
    from benchmarks.studio_browser import StudioPage, chromium, free_port, studio_process

    edges = read_edges(run_loops)
    by_id = {e.edge_id: e for e in edges}
    decided = [e.match["slam"] for e in edges]
    assert any(d["injected"] and d["kept"] for d in decided)
    assert all({"cut", "residual", "group", "injected"} <= set(d) for d in decided)
    port = free_port()
    args = ["label", str(run_loops), "--workspace", str(tmp_path / "ws"), "--no-model",
            "--no-trainer"]  # fmt: skip
    with studio_process(args, port) as proc, chromium() as browser:
        assert proc.stdout is not None
        printed = proc.stdout.readline().strip()
        while not printed.startswith("link to an edge:"):
            printed = proc.stdout.readline().strip()
        assert "queue=kept-failure" in printed, printed
        tab = StudioPage(browser.new_page(), f"http://127.0.0.1:{port}")
        tab.choose_queue("kept by the run, labelled failure")
        first = by_id[tab.edge_id() or ""]
        assert first.match["slam"]["injected"] and first.match["slam"]["kept"]
        assert first.label == "failure"
        assert f"?edge={first.edge_id}" in printed
        panel = tab.page.locator("table").last.inner_text()
        assert "injected (a false loop put in on purpose)" in panel
        assert "p –, cut –" in panel  # no validator: no p, no cut, and it says so
        assert "not-checked" in panel and "kept in the graph" in panel
        assert "after graph vs this edge" in panel
        header = tab.page.locator("p").filter(has_text="run:").first.inner_text()
        kept = sum(d["kept"] for d in decided)
        assert f"{kept} kept · {len(edges) - kept} rejected" in header
        # The printed link opens the same edge; tall enough to show the header and the facts.
        shown = browser.new_page()
        shown.set_viewport_size({"width": 1400, "height": 1250})
        linked = StudioPage(shown, printed.removeprefix("link to an edge: "))
        assert linked.edge_id() == first.edge_id
        linked.screenshot(artifacts / "studio-run-decisions.png")

        # A link to the last edge opens it, in the queue it names. How fast (the target is 2 s
        # of the load) is measured on a quiet machine by benchmarks/bench_studio.py: here the
        # other test worker shares the cores.
        target = edges[-1]
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{port}/?edge={target.edge_id}&queue=kept")
        loaded = time.perf_counter()
        # Polled inside the page at every frame: the time is the studio's, not the polling's.
        page.wait_for_function(
            "id => [...document.querySelectorAll('code')].some(c => c.innerText.trim() === id)",
            arg=target.edge_id,
            polling="raf",
            timeout=10_000,
        )
        seconds = time.perf_counter() - loaded
        assert seconds <= 10.0, seconds
        assert "kept by the run" in page.locator("p").filter(has_text=" · ").first.inner_text()
