"""The model's p(success) arrives edge on screen first, with progress, not after minutes."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from benchmarks.studio_browser import StudioPage, chromium, free_port
from vgm_studio.labels import LabelStore
from vgm_studio.matching.edges import read_edges
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.studio.app import Studio, StudioConfig
from vgm_studio.studio.panel import facts_text
from vgm_studio.studio.scoring import Scorer, model_key


@pytest.fixture
def store(office_edges, tmp_path):
    opened = LabelStore(tmp_path / "ws")
    opened.add_edges(read_edges(office_edges))
    yield opened
    opened.close()


def test_the_edges_on_screen_are_scored_first_and_progress_is_told(store):
    ids = store.edge_ids()
    on_screen = ids[-3:]  # the log's last edges: today scored last of all
    calls: list[list[str]] = []
    shown: list[tuple[int, int] | None] = []

    def predict(edges):
        calls.append([e.edge_id for e in edges])
        return np.full(len(edges), 0.7)

    scorer = Scorer(
        store,
        BUNDLED_MODEL,
        wanted=lambda: on_screen,
        show=lambda _scores, progress: shown.append(progress),
        predict=predict,
        batch=50,
    )
    scorer.run()
    assert calls[0] == on_screen
    assert sorted(scorer.order) == sorted(ids) and len(scorer.order) == len(ids)
    counts = [p for p in shown if p is not None]
    assert counts[0] == (0, len(ids)) and counts[1] == (3, len(ids))
    assert [c[0] for c in counts] == sorted(c[0] for c in counts)
    assert counts[-1] == (len(ids), len(ids)) and shown[-1] is None  # stored, then done
    stored = store.predictions()
    assert stored.model == model_key(BUNDLED_MODEL, None) and len(stored.p) == len(ids)


def test_the_bundled_model_scores_a_workspace_as_before(store):
    """With the real model: the stored scores are probabilities, and running again is free."""
    scorer = Scorer(store, BUNDLED_MODEL, wanted=lambda: [], show=lambda *_: None, batch=64)
    scorer.run()
    p = store.predictions().p
    assert len(p) == store.count_edges() and all(0.0 <= v <= 1.0 for v in p.values())
    again = Scorer(store, BUNDLED_MODEL, wanted=lambda: [], show=lambda *_: None)
    again.run()
    assert again.order == []  # this model's scores are there: nothing to do


def test_the_panel_says_how_far_scoring_got(office_edges):
    edge = read_edges(office_edges)[0]
    text = facts_text(edge, {}, None, 0.5, False, scoring=(4200, 15630))
    assert "scoring 4,200 / 15,630" in text and "no model" not in text
    assert "no model" in facts_text(edge, {}, None, 0.5, False)


@pytest.mark.slow
@pytest.mark.usefixtures("needs_chromium")
def test_a_tab_shows_its_edges_score_while_the_rest_are_scored(store):
    release = threading.Event()

    def predict(edges):
        if len(edges) > 4:  # the rest of the queue waits until the test lets it go
            release.wait(60)
        return np.full(len(edges), 0.83)

    studio = Studio(store, StudioConfig(port=free_port(), annotator="ana"))
    studio.start()
    try:
        with chromium() as browser:
            tab = StudioPage(browser.new_page(), studio.url)
            # A model that is slow on all but the wanted edges.
            scorer = Scorer(
                store, BUNDLED_MODEL, studio.upcoming, studio.show_scores, predict=predict
            )
            scorer.start()
            total = store.count_edges()
            tab.wait_for(lambda: "0.83" in tab.page.inner_text("body"))  # the edge on screen
            for _ in range(5):  # past the edges scored first
                tab.press("e")
            tab.wait_for(lambda: f"scoring 4 / {total}" in tab.page.inner_text("body"))
            release.set()
            scorer.join(60)
            tab.wait_for(lambda: "0.83" in tab.page.inner_text("body"))
            assert "scoring" not in tab.page.inner_text("body")
    finally:
        release.set()
        studio.stop()
