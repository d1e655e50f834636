"""Two studio servers on one store: a second ``vgm-studio label --port 8081`` on a workspace.

They hand no edge to two annotators (SQLite and PostgreSQL, as tabs of one server do), and the
second uses the first one's trainer instead of crashing against its lock.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from benchmarks.studio_browser import StudioPage, chromium, free_port
from vgm_studio.labels import LabelStore
from vgm_studio.labels.postgres import PgLabelStore
from vgm_studio.matching.edges import read_edges
from vgm_studio.studio.app import Studio, StudioConfig
from vgm_studio.studio.team import StoreLink
from vgm_studio.trainer import TrainerSupervisor
from vgm_studio.trainer.lock import held_elsewhere
from vgm_studio.trainer.registry import read_state
from vgm_studio.trainer.supervisor import Backoff


def _stores(kind: str, office_edges: Path, tmp_path: Path, pg_server: object) -> list[LabelStore]:
    """Two stores on one workspace (or team database), each as one server opens it."""
    edges = read_edges(office_edges)
    if kind == "sqlite":
        first = LabelStore(tmp_path / "ws")
        first.add_edges(edges)
        return [first, LabelStore(tmp_path / "ws")]
    url = pg_server()  # type: ignore[operator]
    first = PgLabelStore(url, models_dir=tmp_path)
    first.add_edges(edges)
    return [first, PgLabelStore(url, models_dir=tmp_path)]


@pytest.fixture(params=["sqlite", "postgres"])
def two_stores(request, office_edges, tmp_path):
    pg = request.getfixturevalue("pg_server") if request.param == "postgres" else None
    stores = _stores(request.param, office_edges, tmp_path, pg)
    yield stores
    for store in stores:
        store.close()


def test_claims_hold_between_two_servers_on_one_store(two_stores):
    first, second = (StoreLink(store, lambda _line: None) for store in two_stores)
    edge, other = two_stores[0].edge_ids()[:2]
    assert first.claim(edge, 1)
    assert not second.claim(edge, 1)  # same tab number, another server: refused
    assert second.claim(other, 1)
    first.release(1)
    assert second.claim(edge, 2)  # given back, free for anyone


@pytest.mark.slow
@pytest.mark.usefixtures("needs_chromium")
def test_two_servers_on_one_store_never_show_two_tabs_the_same_edge(two_stores):
    studios = [Studio(store, StudioConfig(port=free_port(), annotator="a")) for store in two_stores]
    for studio in studios:
        studio.start()
    try:
        with chromium() as browser:
            tabs = [StudioPage(browser.new_page(), studio.url) for studio in studios]
            seen = [{tab.edge_id()} for tab in tabs]
            assert tabs[0].edge_id() != tabs[1].edge_id()
            for step in range(6):  # label on alternate servers; never the other's edge
                tabs[step % 2].press("s")
                shown = [tab.edge_id() for tab in tabs]
                assert None not in shown and shown[0] != shown[1], shown
                seen[step % 2].add(shown[step % 2])
            assert not (seen[0] & seen[1])
            labels = two_stores[0].label_map()
            assert len(labels) == 6 and all(len(v) == 1 for v in labels.values())
    finally:
        for studio in studios:
            studio.stop()


def _wait(condition, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.2)


@pytest.mark.long
def test_a_second_studio_uses_the_running_trainer_and_takes_over_when_it_ends(
    office_edges, tmp_path
):
    store = LabelStore(tmp_path / "ws")
    store.add_edges(read_edges(office_edges))
    quick = Backoff(first=0.2, longest=0.5, standby=0.2)
    first = TrainerSupervisor(store.workspace, backoff=quick)
    second = TrainerSupervisor(store.workspace, backoff=quick)
    first.start()
    try:
        _wait(lambda: held_elsewhere(store.workspace))  # the first trainer holds its lock
        second.start()
        time.sleep(3.0)  # once refused, the second restarted in a loop and said "crashed"
        assert second.standing_by and second.pid is None and second.restarts == 0
        assert read_state(store).get("state") != "crashed"
        assert "crashed" not in second.log_path.read_text()
        first.stop()
        _wait(lambda: second.pid is not None and not second.standing_by)
        _wait(lambda: held_elsewhere(store.workspace))  # now the second's trainer holds it
    finally:
        second.stop()
        first.stop()
        store.close()


def test_a_team_stores_running_trainer_is_seen(pg_server, tmp_path):
    url = pg_server()
    trainer = PgLabelStore(url, models_dir=tmp_path)
    assert not held_elsewhere(tmp_path, url)
    trainer.trainer_lock()
    assert held_elsewhere(tmp_path, url)
    trainer.close()  # the lock goes with the connection, as with a killed trainer
    _wait(lambda: not held_elsewhere(tmp_path, url), timeout=10)
