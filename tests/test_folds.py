"""Leave-one-building-out folds (benchmarks/folds.py) on tiny edge files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from benchmarks.folds import Building, make_folds
from vgm_studio.matching.edges import read_edges, write_edges


def _copy(edges, out: Path, log: str, kind: str | None = None) -> Path:
    """The edges as if from another log (``log`` as its hash), optionally one kind only."""
    kept = [e for e in edges if kind is None or e.kind == kind]
    write_edges(out, [dataclasses.replace(e, log_sha256=log, log_path=f"{log}.log") for e in kept])
    return out


@pytest.fixture
def buildings(office_edges, tmp_path) -> tuple[list[Building], list[Path]]:
    found = read_edges(office_edges)
    edges = [e for e in found if e.kind == "sequential"][:6] + [
        e for e in found if e.kind == "loop"
    ][:6]
    made = [
        Building(
            name,
            _copy(edges, tmp_path / f"{name}-train.jsonl", f"log-{name}"),
            _copy(edges, tmp_path / f"{name}-loops.jsonl", f"log-{name}", "loop"),
        )
        for name in ("a", "b", "c")
    ]
    return made, [_copy(edges, tmp_path / "sim.jsonl", "log-sim")]


def test_each_building_held_out_once_and_never_on_both_sides(buildings):
    made, sims = buildings
    folds = make_folds(made, sims)
    assert [f.held_out for f in folds] == ["a", "b", "c"]
    for fold in folds:
        test_logs = {e.log_sha256 for e in read_edges(fold.test)}
        train_logs = {e.log_sha256 for f in fold.train for e in read_edges(f)}
        assert test_logs == {f"log-{fold.held_out}"}
        assert not test_logs & train_logs
        assert train_logs == {"log-sim"} | {f"log-{n}" for n in "abc" if n != fold.held_out}


def test_subset_of_buildings_and_unknown_names(buildings):
    made, sims = buildings
    assert [f.held_out for f in make_folds(made, sims, ["c"])] == ["c"]
    with pytest.raises(ValueError, match="unknown building"):
        make_folds(made, sims, ["z"])


def test_a_log_on_both_sides_is_refused(buildings, tmp_path):
    made, sims = buildings
    # "d" is building "a" again under another name: holding out d would train on its log.
    edges = read_edges(made[0].train)
    twin = Building("d", made[0].train, _copy(edges, tmp_path / "d.jsonl", "log-a", "loop"))
    with pytest.raises(ValueError, match="also trains on its log"):
        make_folds([*made, twin], sims, ["d"])


def test_paired_table_says_which_leads_chance_can_explain(monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(Path(__file__).parents[1] / "benchmarks"))
    import bench_generalisation

    right = {
        # vgmnet right on all ten pairs rgb-baseline gets wrong: 2 / 2^10.
        ("big", "vgmnet"): [True] * 10,
        ("big", "rgb-baseline"): [False] * 10,
        ("even", "vgmnet"): [True, False],
        ("even", "rgb-baseline"): [False, True],
        # One pair in three: behind, but nothing chance cannot explain.
        ("small", "vgmnet"): [True, True, False],
        ("small", "rgb-baseline"): [True, True, True],
        ("score-only", "score"): [True],
    }
    bench_generalisation._paired(right)
    lines = capsys.readouterr().out.splitlines()
    rows = {line.split("|")[1].strip(): line for line in lines if line.startswith("|")}
    # The summary counts the same arrays: one lead beyond chance, one trail within it.
    assert lines[-1] == (
        "vgmnet ahead of rgb-baseline on accuracy: 1 of 3 buildings (1 beyond chance); "
        "behind beyond chance on 0"
    )
    assert "| 10 " in rows["big"] and "0.002" in rows["big"] and "chance" not in rows["big"]
    assert rows["big"].rstrip(" |").endswith("vgmnet")
    assert "level" in rows["even"] and "1.000" in rows["even"]
    assert "rgb-baseline (chance can explain it)" in rows["small"]
    assert "score-only" not in rows


def test_epochs_per_model_or_for_all(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).parents[1] / "benchmarks"))
    import argparse

    import bench_generalisation

    parse = bench_generalisation._epochs
    assert parse("vgmnet=12,rgb-baseline=4") == {"vgmnet": 12, "rgb-baseline": 4}
    # One number is every model's; a model left out keeps its recipe (dict.get -> None).
    assert parse("12") == dict.fromkeys(bench_generalisation.MODELS, 12)
    assert parse("vgmnet=20") == {"vgmnet": 20}
    for bad, why in [("vgmnet=x", "not a number"), ("resnet=3", "unknown model"), ("0", "1 or")]:
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            parse(bad)
