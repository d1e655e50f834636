"""Training on too few labels is refused in one line, and no figure is ever printed as nan."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.untrusted import label_row, write_jsonl, write_log
from vgm_studio.core.hashing import content_hash
from vgm_studio.matching.edges import Edge, edge_id
from vgm_studio.model.training import MIN_PER_CLASS


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("vgm-studio")
    cmd = [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]
    return subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True, timeout=600)


def export(folder: Path, labels: list[str]) -> Path:
    """An export (``vgm-studio export``'s JSONL) with these labels, over a real tiny log."""
    log = write_log(folder)
    sha = content_hash(log)
    rows = []
    for k, label in enumerate(labels):
        a = k % 5
        # A success matches well and a failure badly: the score model has something to fit.
        good = label == "success"
        estimate = [0.1, 0.0, 0.001 * k]
        edge = Edge(
            edge_id=edge_id(sha, a, a + 1, estimate),
            log_path=str(log.resolve()),
            log_sha256=sha,
            a=a,
            b=a + 1,
            timestamp_a=a + 0.5,
            timestamp_b=a + 1.5,
            kind="loop",
            guess=[0.1, 0.0, 0.0],
            estimate=estimate,
            match={
                "iterations": 3 if good else 30,
                "converged": good,
                "inlier_ratio": 0.9 - 0.01 * (k % 7) if good else 0.2 + 0.01 * (k % 7),
                "residual": 0.01 if good else 0.2,
            },
            reference=[0.1, 0.0, 0.0],
            label=label,
            params={"read": {"poses": "auto"}},
        )
        rows.append(label_row(edge, label=label))
    return write_jsonl(folder / "labels.jsonl", rows)


def test_a_three_label_export_is_refused_in_one_line(tmp_path: Path) -> None:
    labels = export(tmp_path, ["success", "success", "failure"])
    out = tmp_path / "m.pt"
    proc = run("train", labels, "--out", out)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines == [
        f"vgm-studio: error: {labels}: 2 success and 1 failure edges; training needs at "
        f"least {MIN_PER_CLASS} of each (a share of each class is held out to stop early, "
        "choose the p(success) cut and give the figures): label more edges"
    ]
    assert not out.exists() and not out.with_name("m.pt.partial").exists()


def test_the_minimum_is_stated_in_help() -> None:
    proc = run("train", "--help")
    text = " ".join(proc.stdout.split())
    assert f"Needs at least {MIN_PER_CLASS} edges labelled success and {MIN_PER_CLASS}" in text


def test_one_short_of_the_minimum_is_refused_and_the_minimum_trains(tmp_path: Path) -> None:
    short = export(tmp_path, ["success"] * MIN_PER_CLASS + ["failure"] * (MIN_PER_CLASS - 1))
    proc = run("train", short, "--model", "score", "--out", tmp_path / "s.pt")
    assert proc.returncode == 1 and f"{MIN_PER_CLASS - 1} failure edges" in proc.stderr
    enough = export(tmp_path, ["success", "failure"] * MIN_PER_CLASS)
    proc = run("train", enough, "--model", "score", "--out", tmp_path / "s.pt")
    assert proc.returncode == 0, proc.stderr
    assert "nan" not in proc.stdout.lower()
    assert "validation: accuracy " in proc.stdout


def test_no_validation_split_says_na_and_why(tmp_path: Path) -> None:
    labels = export(tmp_path, ["success", "failure"] * MIN_PER_CLASS)
    model = tmp_path / "s.pt"
    proc = run("train", labels, "--model", "score", "--val-fraction", "0", "--out", model)
    assert proc.returncode == 0, proc.stderr
    assert "nan" not in (proc.stdout + proc.stderr).lower()
    assert "validation: n/a (no edge was held out for validation; raise --val-fraction)" in (
        proc.stdout
    )


@pytest.mark.parametrize("only", ["success", "failure"])
def test_eval_on_one_class_gives_auc_na(tmp_path: Path, only: str) -> None:
    (tmp_path / "train").mkdir()
    (tmp_path / "judge").mkdir()
    model = tmp_path / "s.pt"
    labels = export(tmp_path / "train", ["success", "failure"] * MIN_PER_CLASS)
    assert run("train", labels, "--model", "score", "--out", model).returncode == 0
    one_class = export(tmp_path / "judge", [only] * 4)
    figures = tmp_path / "eval.json"
    proc = run("eval", model, one_class, "--json", figures)
    assert proc.returncode == 0, proc.stderr
    assert "nan" not in proc.stdout.lower()
    assert f"ROC AUC    n/a (needs both classes; these edges are all {only})" in proc.stdout
    doc = json.loads(figures.read_text(), parse_constant=lambda c: pytest.fail(f"JSON has {c}"))
    assert doc["auc"] is None and doc["n"] == 4
