"""The label store: committed labels, undo as history, conflicts, versions, export and import.

The store's tests run against both backends: SQLite in a workspace folder and a real
PostgreSQL server (``pg_server`` in conftest.py); team-only guarantees are in test_team_store.py.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable

import pytest

from vgm_studio.errors import InputError
from vgm_studio.labels import LabelStore
from vgm_studio.labels.postgres import PgLabelStore
from vgm_studio.labels.transfer import export_labels, import_labels
from vgm_studio.matching.edges import read_edges

BACKENDS = ["sqlite", "postgresql"]


@pytest.fixture(params=BACKENDS)
def new_store(request, tmp_path) -> Callable[[], LabelStore]:
    """Makes empty stores of one backend: workspace folders, or databases on the test server."""
    made: list[LabelStore] = []
    count = iter(range(100))

    def make() -> LabelStore:
        if request.param == "sqlite":
            s = LabelStore(tmp_path / f"ws{next(count)}")
        else:
            url = request.getfixturevalue("pg_server")()
            s = PgLabelStore(url, models_dir=tmp_path / f"models{next(count)}")
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


def _reopen(store: LabelStore) -> LabelStore:
    """A second store on the same data, as another process or server opens it."""
    if isinstance(store, PgLabelStore):
        return PgLabelStore(store.url, models_dir=store.workspace)
    return LabelStore(store.workspace)


@pytest.fixture
def store(new_store, office_edges) -> LabelStore:
    s = new_store()
    s.add_edges(read_edges(office_edges))
    return s


def test_every_label_is_committed_and_seen_by_another_connection(store):
    first = store.edge_ids()[0]
    store.label(first, "ana", "success", note="clean corridor")
    other_store = _reopen(store)  # another process would be the same
    assert [(r.label, r.note) for r in other_store.labels()] == [("success", "clean corridor")]
    other_store.close()


def test_a_sqlite_label_is_in_the_file_at_once(tmp_path, office_edges):
    store = LabelStore(tmp_path / "ws")
    store.add_edges(read_edges(office_edges))
    store.label(store.edge_ids()[0], "ana", "success", note="clean corridor")
    other = sqlite3.connect(store.path)
    assert other.execute("SELECT label, note FROM labels").fetchall() == [
        ("success", "clean corridor")
    ]
    assert other.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_undo_appends_history_and_restores_the_previous_label(store):
    edge = store.edge_ids()[3]
    first = store.label(edge, "ana", "success")
    second = store.label(edge, "ana", "failure", note="slid one door")
    store.undo(second.id)
    assert [(r.label, r.note) for r in store.labels(edge)] == [("success", "")]
    assert store.labels(edge)[0].labeled_at == first.made_at
    store.undo(first.id)
    assert store.labels(edge) == []
    actions = [(e.action, e.label) for e in store.history(edge)]
    assert actions == [
        ("label", "success"),
        ("label", "failure"),
        ("undo", "success"),
        ("undo", None),
    ]
    with pytest.raises(ValueError, match="undone already"):
        store.undo(first.id)


def test_undo_refuses_a_label_overtaken_by_a_later_one(store):
    edge = store.edge_ids()[1]
    old = store.label(edge, "ana", "success")
    store.label(edge, "ana", "failure")
    with pytest.raises(ValueError, match="overtaken"):
        store.undo(old.id)


def test_two_annotators_who_disagree_are_both_kept(store):
    edge = store.edge_ids()[2]
    store.label(edge, "ana", "success")
    store.label(edge, "ben", "failure")
    assert store.label_map()[edge] == {"ana": "success", "ben": "failure"}


def test_candidates_made_again_keep_their_labels(store, office_edges):
    edge = store.edge_ids()[5]
    store.label(edge, "ana", "failure")
    count = store.count_edges()
    assert store.add_edges(read_edges(office_edges)) == 0
    assert store.count_edges() == count
    assert store.label_map()[edge] == {"ana": "failure"}


def test_a_workspace_of_another_schema_is_refused(tmp_path):
    LabelStore(tmp_path / "ws").close()
    db = sqlite3.connect(tmp_path / "ws" / "labels.sqlite")
    db.execute("UPDATE meta SET value = '99' WHERE key = 'schema'")
    db.commit()
    with pytest.raises(InputError, match="schema 99"):
        LabelStore(tmp_path / "ws")


def test_a_foreign_database_is_refused(tmp_path):
    (tmp_path / "ws").mkdir()
    (tmp_path / "ws" / "labels.sqlite").write_bytes(b"definitely not sqlite" * 100)
    with pytest.raises(InputError, match="not a VGM Studio workspace"):
        LabelStore(tmp_path / "ws")


@pytest.mark.parametrize("suffix", [".jsonl", ".csv"])
def test_export_then_import_gives_the_same_store(store, new_store, tmp_path, suffix):
    ids = store.edge_ids()
    store.label(ids[0], "ana", "success", note='says "fine", really')
    store.label(ids[1], "ana", "failure")
    store.label(ids[1], "ben", "success", note="line\nbreak")
    out = tmp_path / f"labels{suffix}"
    assert export_labels(store, out) == 3
    fresh = new_store()
    assert import_labels(fresh, out) == (2, 3)
    assert fresh.labels() == store.labels()
    assert [fresh.edge(i).to_json() for i in ids[:2]] == [store.edge(i).to_json() for i in ids[:2]]
    again = tmp_path / f"again{suffix}"
    export_labels(fresh, again)
    assert again.read_bytes() == out.read_bytes()
    assert import_labels(fresh, out) == (0, 0)  # importing twice changes nothing


def test_exported_jsonl_is_a_training_file(store, tmp_path):
    ids = store.edge_ids()
    store.label(ids[0], "ana", "failure")
    out = tmp_path / "labels.jsonl"
    export_labels(store, out)
    (edge,) = read_edges(out)
    assert edge.label == "failure"


def test_a_bad_import_line_names_file_and_line_and_changes_nothing(store, new_store, tmp_path):
    ids = store.edge_ids()
    store.label(ids[0], "ana", "success")
    good = tmp_path / "labels.jsonl"
    export_labels(store, good)
    bad = tmp_path / "bad.jsonl"
    line = good.read_text().strip()
    bad.write_text(line + "\n" + line.replace('"label":"success"', '"label":"maybe"') + "\n")
    fresh = new_store()
    with pytest.raises(InputError) as err:
        import_labels(fresh, bad)
    assert str(err.value) == f"{bad}:2: label: Input should be 'success' or 'failure'"
    assert fresh.count_edges() == 0
    txt = tmp_path / "labels.txt"
    txt.write_text(line + "\n")
    with pytest.raises(InputError, match=r"unknown label file type '\.txt'"):
        import_labels(fresh, txt)


def test_a_status_read_does_not_wait_for_another_process_writing(tmp_path, office_edges):
    import time

    store = LabelStore(tmp_path / "ws")
    store.add_edges(read_edges(office_edges))
    store.trainer.report({"state": "idle"})  # the trainer's tables exist
    # Another process (the trainer) holds the write lock, mid-way through storing a version.
    writer = sqlite3.connect(store.path, isolation_level=None)
    writer.execute("BEGIN IMMEDIATE")
    writer.execute("INSERT INTO meta VALUES ('active_model', 'v9')")
    start = time.perf_counter()
    view = store.trainer.view()
    count = store.count_edges()
    assert time.perf_counter() - start < 0.5
    assert count > 0 and view.active_model is None  # not the uncommitted row
    writer.execute("COMMIT")
    assert store.trainer.view().active_model == "v9"
    writer.close()
