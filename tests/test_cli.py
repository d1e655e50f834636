"""The ``vgm-studio`` command as a user runs it: real processes, real files, exit codes."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest


def run(*args: str | Path, ok: bool = True) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("vgm-studio")
    cmd = [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]
    proc = subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True, timeout=600)
    if ok:
        assert proc.returncode == 0, proc.stderr
    return proc


def one_line_error(proc: subprocess.CompletedProcess[str]) -> str:
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


@pytest.mark.long
def test_info_reads_every_shared_log(datasets):
    logs = [p for p in sorted(datasets.rglob("*")) if p.suffix in {".clf", ".log"}]
    for path in logs:
        out = run("info", path, "--json").stdout
        summary = json.loads(out)
        assert summary["scans"] > 100, path
        assert summary["travelled_m"] > 50, path
    table = run("info", datasets / "intel" / "intel.clf").stdout
    assert (
        "13,631" in table and "-90° … +89° in 1° steps" in table and "odometry (raw log)" in table
    )
    relations = run("info", datasets / "intel" / "intel.relations").stdout
    assert "2984 relations" in relations


def test_info_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.log"
    bad.write_text("FLASER 3 1 1 1 0 0 0 0 0 0 5 h 5\nFLASER 3 1 1\n")
    proc = run("info", bad, ok=False)
    assert proc.returncode == 1
    assert one_line_error(proc) == (
        f"vgm-studio: error: {bad}:2: FLASER: expected at least 11 fields "
        "(3 ranges and two poses), found 4"
    )
    skipped = run("info", bad, "--skip-bad-lines")
    assert "skipped 1 malformed line" in skipped.stderr
    missing = run("info", tmp_path / "none.log", ok=False)
    assert missing.returncode == 1 and "none.log: no such file" in one_line_error(missing)
    unknown = run("info", bad, "--frobnicate", ok=False)
    assert unknown.returncode == 2 and "No such option: --frobnicate" in one_line_error(unknown)
    wrong = run("info", bad, "--poses", "guess", ok=False)
    assert wrong.returncode == 2 and "--poses" in one_line_error(wrong)


@pytest.mark.long
def test_candidates_on_intel_give_both_labels_and_stable_ids(datasets, tmp_path, artifacts):
    log = datasets / "intel" / "intel.gfs.log"
    out1, out2 = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    proc = run("candidates", log, "--out", out1, "--max", "300", "--seed", "3")
    assert "wrote" in proc.stdout
    run("candidates", log, "--out", out2, "--max", "300", "--seed", "3", "--no-sequential")
    edges = [json.loads(line) for line in out1.read_text().splitlines()]
    loops = [e for e in edges if e["kind"] == "loop"]
    assert len(loops) == 300 and len(edges) == 300 + 909
    labels = {e["label"] for e in loops}
    assert {"success", "failure"} <= labels
    first = loops[0]
    assert first["log_sha256"] == "b066a0e3c62e69901540895017871835169d13c56a4cbb78f42599cf3563484f"
    assert first["b"] - first["a"] >= 50
    assert first["params"]["candidates"]["max_loops"] == 300
    assert first["params"]["candidates"]["noise_xy"] == 0.3
    assert first["params"]["labels"]["success_xy"] == 0.10
    assert {"iterations", "inlier_ratio", "residual", "covariance"} <= set(first["match"])
    again = {e["edge_id"] for e in map(json.loads, out2.read_text().splitlines())}
    assert {e["edge_id"] for e in loops} == again

    success = next(e for e in loops if e["label"] == "success")
    png = artifacts / "intel-success-edge.png"
    run("vgm", out1, "--edge", success["edge_id"][:10], "--png", png)
    img = cv2.imread(str(png))
    # The rectangle around the pair at 4 pixels or more a cell, under a caption.
    assert img is not None and img.shape[1] >= 600 and img.shape[0] > 200
    # Both scans are drawn, each in its own colour.
    for bgr in ((255, 170, 40), (30, 140, 255)):
        assert (np.abs(img.astype(int) - bgr).sum(axis=2) < 30).sum() > 200
    bad = run("vgm", out1, "--edge", "zzzz", "--png", png, ok=False)
    assert bad.returncode == 1 and "no edge with id 'zzzz'" in one_line_error(bad)


def test_candidates_from_relations_on_raw_intel(datasets, tmp_path):
    out = tmp_path / "rel.jsonl"
    run(
        "candidates",
        datasets / "intel" / "intel.clf",
        "--reference",
        datasets / "intel" / "intel.relations",
        "--out",
        out,
        "--max",
        "150",
        "--no-sequential",
    )
    edges = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(edges) == 150
    assert all(e["reference"] is not None and e["label"] for e in edges)
    assert edges[0]["params"]["loop_source"] == "relations"
    assert sum(e["label"] == "success" for e in edges) > 50


@pytest.mark.parametrize(
    "args",
    [
        ("vgm", "nope.jsonl", "--edge", "x", "--png", "x.png"),
        ("candidates", "nope.log", "--out", "x.jsonl"),
    ],
)
def test_missing_inputs(tmp_path, args):
    proc = run(*args, ok=False)
    assert proc.returncode == 1 and "nope" in one_line_error(proc)


def test_help_lists_commands():
    out = run("--help").stdout
    for name in ("info", "simulate", "candidates", "vgm", "demo"):
        assert name in out
    assert Path(shutil.which("vgm-studio") or "").name in {"vgm-studio", ""}


def test_ctrl_c_ends_a_command_with_130_and_a_word(tmp_path, monkeypatch, capsys):
    """typer turns Ctrl-C into exit code 130, which outside its standalone mode comes back as
    a value: a run stopped half-way once ended silently with 0, and `slam … && next` went on."""
    from vgm_studio.services import info as service
    from vgm_studio.tools import cmd

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(service, "describe", stopped)
    log = tmp_path / "one.log"
    log.write_text("FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 0 host 0\n")
    with pytest.raises(SystemExit) as stop:
        cmd.main(["info", str(log)])
    assert stop.value.code == 130
    assert capsys.readouterr().err.strip() == "vgm-studio: interrupted"
