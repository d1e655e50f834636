"""A seeded fuzzer over every reader and ``import``: accepted, or refused in one clean line.

Each reader is called in-process on mutations of a valid file (a few hundred cases in all,
derandomised so CI sees the same cases every run); a small sample runs the real command line.
A refused import must leave every row of the store as it was.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.studio_browser import free_port
from tests.fuzzing import (
    BYTE_OPS,
    BYTE_PAYLOADS,
    VALUE_PAYLOADS,
    check_outcome,
    mutate_bytes,
    mutate_json_rows,
    store_rows,
)
from tests.test_cli_checks import run
from tests.untrusted import seed_files
from vgm_studio.datasets import open_log
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.relations import read_relations
from vgm_studio.labels import LabelStore
from vgm_studio.labels.transfer import import_labels
from vgm_studio.matching.edges import read_edges

FUZZ = settings(
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
byte_ops = st.lists(
    st.tuples(
        st.sampled_from(BYTE_OPS),
        st.floats(0, 1, exclude_max=True),
        st.integers(0, 10 * len(BYTE_PAYLOADS)),
    ),
    min_size=1,
    max_size=4,
)
field_ops = st.lists(
    st.tuples(
        st.just("field"),
        st.floats(0, 1, exclude_max=True),
        st.integers(0, 40 * len(VALUE_PAYLOADS)),
    ),
    min_size=1,
    max_size=3,
)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, Path]:
    """Valid files of every kind, with a real log behind the edges and labels."""
    return seed_files(tmp_path_factory.mktemp("fuzz"))


def _mutant(seeds: dict[str, Path], kind: str, data: bytes, suffix: str) -> Path:
    path = seeds["log"].parent / f"mutant-{kind}{suffix}"
    path.write_bytes(data)
    return path


@settings(FUZZ, max_examples=100)
@given(ops=byte_ops, skip=st.booleans())
def test_carmen_reader(seeds, ops, skip):
    path = _mutant(seeds, "log", mutate_bytes(seeds["log"].read_bytes(), ops), ".log")
    check_outcome(lambda: open_log(path, ReadOptions(skip_bad_lines=skip)))


@settings(FUZZ, max_examples=50)
@given(ops=byte_ops)
def test_relations_reader(seeds, ops):
    data = mutate_bytes(seeds["relations"].read_bytes(), ops)
    path = _mutant(seeds, "rel", data, ".relations")
    check_outcome(lambda: read_relations(path))


@settings(FUZZ, max_examples=80)
@given(ops=st.one_of(byte_ops, field_ops))
def test_edges_reader(seeds, ops):
    if ops[0][0] == "field":
        rows = [json.loads(x) for x in seeds["edges"].read_text().splitlines()]
        data = mutate_json_rows(rows, ops)
    else:
        data = mutate_bytes(seeds["edges"].read_bytes(), ops)
    path = _mutant(seeds, "edges", data, ".jsonl")
    check_outcome(lambda: read_edges(path))


@pytest.fixture(scope="module")
def target(tmp_path_factory, seeds) -> LabelStore:
    """A store that already holds labels: what a refused import must leave untouched."""
    store = LabelStore(tmp_path_factory.mktemp("target") / "ws")
    import_labels(store, seeds["labels.jsonl"])
    return store


def _import_keeps_store_on_refusal(target: LabelStore, path: Path) -> None:
    before = store_rows(target.path)
    if check_outcome(lambda: import_labels(target, path)) == "refused":
        assert store_rows(target.path) == before


@settings(FUZZ, max_examples=80)
@given(ops=st.one_of(byte_ops, field_ops))
def test_import_jsonl(seeds, target, ops):
    if ops[0][0] == "field":
        rows = [json.loads(x) for x in seeds["labels.jsonl"].read_text().splitlines()]
        data = mutate_json_rows(rows, ops)
    else:
        data = mutate_bytes(seeds["labels.jsonl"].read_bytes(), ops)
    _import_keeps_store_on_refusal(target, _mutant(seeds, "labels", data, ".jsonl"))


@settings(FUZZ, max_examples=60)
@given(ops=byte_ops)
def test_import_csv(seeds, target, ops):
    data = mutate_bytes(seeds["labels.csv"].read_bytes(), ops)
    _import_keeps_store_on_refusal(target, _mutant(seeds, "labels", data, ".csv"))


# The command line on a small fixed sample: exit code, one line on stderr, no traceback.
CLI_SAMPLE = [
    ("info", "log", [("replace", 0.3, 5)]),  # 1e999 in a reading
    ("info", "log", [("insert", 0.5, 14)]),  # an escape sequence
    ("info", "log", [("duplicate", 0.5, 0)]),  # a valid log: its JSON must be standard
    ("info", "relations", [("replace", 0.2, 2)]),  # NaN pose
    ("import", "labels.jsonl", [("insert", 0.4, 11)]),  # 200,000 brackets
    ("import", "labels.jsonl", [("replace", 0.1, 12)]),  # 5,000 digits
    ("import", "labels.csv", [("insert", 0.6, 28)]),  # a cell over 131,072 characters
    ("import", "labels.csv", [("truncate", 0.7, 0)]),
    ("label", "edges", [("insert", 0.0, 0)]),  # Infinity
]


@pytest.mark.parametrize(("command", "kind", "ops"), CLI_SAMPLE)
def test_the_command_line_on_a_sample(seeds, tmp_path, command, kind, ops):
    suffix = {"log": ".log", "relations": ".relations", "edges": ".jsonl"}.get(kind, "")
    suffix = suffix or Path(kind).suffix
    path = tmp_path / f"mutant{suffix}"
    path.write_bytes(mutate_bytes(seeds[kind].read_bytes(), ops))
    workspace = tmp_path / "ws"
    if command == "import":
        LabelStore(workspace).close()
        before = store_rows(workspace / "labels.sqlite")
        proc = run("import", path, "--workspace", workspace)
    elif command == "label":
        proc = run("label", path, "--workspace", workspace, "--port", free_port(), "--no-model")
    else:
        proc = run(command, path, "--json")
    assert proc.returncode in (0, 1), proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) <= 1
    if command == "import" and proc.returncode == 1:
        assert store_rows(workspace / "labels.sqlite") == before
    if command == "label":
        assert proc.returncode == 1  # refused before a server ever starts
    if command == "info" and proc.returncode == 0:
        json.loads(proc.stdout, parse_constant=_refuse)  # standard JSON: no NaN or Infinity


def _refuse(name: str) -> None:
    raise AssertionError(f"info --json printed {name}")
