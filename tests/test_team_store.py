"""The team store on a real PostgreSQL server: what only a shared server has to guarantee.

Several servers on one database, claims across them, one trainer, a wrong schema or URL in one
line, and a server restart that loses no acknowledged label (the short form of
benchmarks/bench_team_store.py).
"""

from __future__ import annotations

import threading

import psycopg
import pytest

from vgm_studio.errors import InputError
from vgm_studio.labels.opening import is_store_url
from vgm_studio.labels.postgres import PgLabelStore
from vgm_studio.matching.edges import read_edges


@pytest.fixture
def url(pg_server, office_edges, tmp_path) -> str:
    made = pg_server()
    store = PgLabelStore(made, models_dir=tmp_path)
    store.add_edges(read_edges(office_edges))
    store.close()
    return made


def test_two_servers_with_eight_annotators_lose_no_label_and_share_no_claim(url, tmp_path):
    servers = [PgLabelStore(url, models_dir=tmp_path) for _ in range(2)]
    ids = servers[0].edge_ids()
    done: dict[str, list[str]] = {}

    def annotate(server: PgLabelStore, name: str) -> None:
        mine = done.setdefault(name, [])
        for edge_id in ids:  # every annotator walks the same queue; claims split it
            if server.claim(edge_id, name):
                server.label(edge_id, name, "success")
                mine.append(edge_id)

    threads = [threading.Thread(target=annotate, args=(servers[i % 2], f"a{i}")) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    labelled = [e for names in done.values() for e in names]
    assert sorted(labelled) == sorted(ids)  # every edge once, by exactly one annotator
    # Each server sees the other's labels: nothing lost, nothing twice.
    for server in servers:
        assert sum(len(v) for v in server.label_map().values()) == len(ids)
        server.close()


def test_a_claim_expires_and_is_released(url, tmp_path):
    store = PgLabelStore(url, models_dir=tmp_path)
    edge = store.edge_ids()[0]
    assert store.claim(edge, "ana", seconds=0.0)
    assert store.claim(edge, "ben")  # ana's claim ran out
    assert not store.claim(edge, "ana")
    store.release("ben")
    assert store.claim(edge, "ana")
    store.close()


def test_labels_acknowledged_before_a_restart_survive_and_a_press_during_it_is_retried(
    pg_server, url, tmp_path
):
    store = PgLabelStore(url, models_dir=tmp_path)
    said: list[str | None] = []
    store.on_connection(said.append)  # what the studio shows in its panel
    ids = store.edge_ids()
    for edge_id in ids[:20]:
        store.label(edge_id, "ana", "failure")
    pg_server.restart()
    store.label(ids[20], "ana", "success")  # the connection died; made again, press retried
    assert store.reconnects == 1
    assert len(said) == 2 and "label store unreachable" in str(said[0]) and said[1] is None
    fresh = PgLabelStore(url, models_dir=tmp_path)
    assert len(fresh.labels()) == 21
    fresh.close()
    store.close()


def test_another_schema_or_a_foreign_database_is_refused_in_one_line(pg_server, url, tmp_path):
    with psycopg.connect(url, autocommit=True) as db:
        db.execute("UPDATE meta SET value = '99' WHERE key = 'schema'")
    with pytest.raises(InputError, match="schema 99") as err:
        PgLabelStore(url, models_dir=tmp_path)
    assert "\n" not in str(err.value)
    foreign = pg_server("foreign")
    with psycopg.connect(foreign, autocommit=True) as db:
        db.execute("CREATE TABLE invoices (id INTEGER)")
    with pytest.raises(InputError, match="not a VGM Studio label store"):
        PgLabelStore(foreign, models_dir=tmp_path)


def test_a_bad_url_or_no_server_is_one_line(tmp_path):
    with pytest.raises(InputError, match="cannot reach the label store") as err:
        PgLabelStore("postgresql://nobody@127.0.0.1:1/none", retry_seconds=0)
    assert "\n" not in str(err.value)
    assert is_store_url("postgresql://u@h/db") and not is_store_url(tmp_path)


def test_one_trainer_per_store(url, tmp_path):
    first = PgLabelStore(url, models_dir=tmp_path)
    second = PgLabelStore(url, models_dir=tmp_path)
    first.trainer_lock()
    with pytest.raises(InputError, match="another trainer"):
        second.trainer_lock()
    first.close()  # the lock goes with the connection, as with a killed trainer
    second.trainer_lock()
    second.close()


def test_a_trainer_on_a_team_store_registers_versions_next_to_it_and_is_alone(
    pg_server, balanced_office_edges, tmp_path
):
    from typer.testing import CliRunner

    from tests.test_trainer import FAST, SMALL, _models_app
    from vgm_studio.trainer import registry
    from vgm_studio.trainer.worker import Job, TrainerConfig, Worker

    url = pg_server("trainer")
    models = tmp_path / "team.models"
    store = PgLabelStore(url, models_dir=models)
    edges = read_edges(balanced_office_edges)
    store.add_edges(edges)
    for e in edges:
        store.label(e.edge_id, "bot", str(e.label))
    store.set_predictions("before", {e.edge_id: 0.5 for e in edges}, 0.5)
    config = TrainerConfig(nice=0, fit=FAST, promotion=SMALL)
    worker = Worker(models, config, log=lambda _s: None, url=url)
    with pytest.raises(InputError, match="another trainer"):
        Worker(models, config, log=lambda _s: None, url=url)
    assert worker.cycle(Job(from_scratch=False, request=0)) == 1
    # Another server on the same database sees the version and its predictions.
    [v1] = registry.list_models(store)
    assert v1.path == models / "models" / "v1.pt" and v1.path.is_file()
    assert store.predictions().model == ("v1" if v1.promoted else "before")
    listed = CliRunner().invoke(
        _models_app(), ["--store", url, "--models-dir", str(models)], catch_exceptions=False
    )
    assert "v1" in listed.output
    worker.store.close()
    store.close()


def test_the_commands_take_a_store_url_in_place_of_a_workspace(pg_server, office_edges, tmp_path):
    from tests.test_cli_checks import one_line_error, run

    url = pg_server("cli")
    store = PgLabelStore(url, models_dir=tmp_path)
    store.add_edges(read_edges(office_edges))
    store.label(store.edge_ids()[0], "ana", "success")
    store.close()
    out = tmp_path / "labels.jsonl"
    proc = run("export", "--store", url, "--out", out)
    assert proc.returncode == 0 and "wrote 1 labels" in proc.stdout, proc.stderr
    other = pg_server("cli_other")
    proc = run("import", out, "--store", other)
    assert proc.returncode == 0 and "1 labels added or updated, 1 new edges" in proc.stdout
    line = one_line_error(run("export", "--store", url, "--workspace", tmp_path, "--out", out), 1)
    assert "exclude each other" in line
    line = one_line_error(run("export", "--out", out), 1)
    assert "give --workspace DIR or --store URL" in line
    line = one_line_error(run("export", "--store", "mysql://x@y/z", "--out", out), 1)
    assert "not a postgresql://" in line
    line = one_line_error(run("export", "--store", "postgresql://x@127.0.0.1:1/z", "--out", out), 1)
    assert "cannot reach the label store" in line
