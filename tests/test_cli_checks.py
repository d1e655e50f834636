"""The command line refuses bad options and bad paths up front, in one line, with exit 1 or 2."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from vgm_studio.vgm.render import GHOST_BGR

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "datasets" / "demo-seed0.log"


def run(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("vgm-studio")
    cmd = [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]
    return subprocess.run(
        [*cmd, *map(str, args)], capture_output=True, text=True, timeout=600, cwd=cwd
    )


def one_line_error(proc: subprocess.CompletedProcess[str], code: int) -> str:
    assert proc.returncode == code, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


CANDIDATE_USAGE = [
    (["--max", "-5"], "--max"),
    (["--max", "0"], "--max"),
    (["--min-gap", "-1"], "--min-gap"),
    (["--keyframe-distance", "-1"], "--keyframe-distance"),
    (["--noise-xy", "-0.1"], "--noise-xy"),
    (["--noise-theta", "nan"], "--noise-theta"),
    (["--max-distance", "0"], "--max-distance"),
    (["--max-angle", "-3"], "--max-angle"),
    (["--time-tolerance", "1e10"], "--time-tolerance"),
    (["--time-tolerance", "0"], "--time-tolerance"),
    (["--time-offset", "inf"], "--time-offset"),
    (["--max-range", "0"], "--max-range"),
    (["--max-range", "inf"], "--max-range"),
    (["--fov", "0"], "--fov"),
    (["--fov", "361"], "--fov"),
    (["--seed", "-1"], "--seed"),
    (["--success-xy", "0.5"], "--success-xy"),
    (["--success-theta", "6"], "--success-theta"),
    (["--no-sequential", "--no-loops"], "--no-loops"),
]


@pytest.mark.parametrize(("extra", "option"), CANDIDATE_USAGE)
def test_candidates_rejects_bad_options_as_usage_errors(tmp_path, extra, option):
    proc = run("candidates", DEMO, "--out", tmp_path / "e.jsonl", *extra)
    assert option in one_line_error(proc, 2)
    assert not (tmp_path / "e.jsonl").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--size", "0"], "--size"),
        (["--resolution", "-1"], "--resolution"),
        (["--sigma", "0"], "--sigma"),
        (["--png", "x.txt"], "must end in .png"),
        (["--png", "x.jpg"], "must end in .png"),
    ],
)
def test_vgm_rejects_bad_options(tmp_path, args, message):
    edges = tmp_path / "e.jsonl"
    edges.write_text("{}\n")
    base = {"--png": str(tmp_path / "x.png")}
    for k, v in zip(args[::2], args[1::2], strict=True):
        base[k] = v
    flat = [x for kv in base.items() for x in kv]
    proc = run("vgm", edges, "--edge", "x", *flat)
    assert message in one_line_error(proc, 2)


def test_vgm_png_folder_binary_and_folder_edges(tmp_path):
    edges = tmp_path / "e.jsonl"
    edges.write_text("{}\n")
    assert "is a folder" in one_line_error(run("vgm", edges, "--edge", "x", "--png", tmp_path), 2)
    binary = tmp_path / "b.jsonl"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    line = one_line_error(run("vgm", binary, "--edge", "x", "--png", tmp_path / "x.png"), 1)
    assert "b.jsonl: not a text edges file" in line
    line = one_line_error(run("vgm", tmp_path, "--edge", "x", "--png", tmp_path / "x.png"), 1)
    assert "is a folder" in line


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_unwritable_outputs_fail_before_any_work(tmp_path):
    line = one_line_error(run("candidates", DEMO, "--out", "/proc/x.jsonl"), 1)
    assert "/proc/x.jsonl: cannot write here" in line
    line = one_line_error(run("candidates", DEMO, "--out", tmp_path), 1)
    assert "is a folder" in line
    existing = tmp_path / "file"
    existing.write_text("")
    line = one_line_error(run("simulate", "--out", existing), 1)
    assert "is a file, not a folder; --out takes a folder" in line
    line = one_line_error(run("slam", DEMO, "--map-png", existing), 1)
    assert "is a file, not a folder; --map-png takes a folder" in line
    assert "/proc/sim: cannot write here" in one_line_error(
        run("simulate", "--out", "/proc/sim"), 1
    )
    # A file where a folder of the path should be: the message names it, not the target.
    line = one_line_error(run("candidates", DEMO, "--out", existing / "sub" / "x.jsonl"), 1)
    assert line.endswith(f"cannot write here ({existing} is a file, not a folder)")


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--beams", "1"], "--beams"),
        (["--fov", "400"], "--fov"),
        (["--max-range", "-1"], "--max-range"),
        (["--scan-spacing", "0"], "--scan-spacing"),
        (["--preset", "nope"], "--preset"),
    ],
)
def test_simulate_errors_name_the_option_and_exit_2(tmp_path, args, option):
    line = one_line_error(run("simulate", "--out", tmp_path, *args), 2)
    assert option in line and "num_beams" not in line and "fov_deg" not in line


def test_relations_file_as_the_log_says_use_reference(datasets, tmp_path):
    rel = datasets / "intel" / "intel.relations"
    line = one_line_error(run("candidates", rel, "--out", tmp_path / "e.jsonl"), 1)
    assert "Freiburg relations file; pass it as --reference" in line
    summary = json.loads(run("info", rel, "--json").stdout)
    assert summary["format"] == "relations" and summary["relations"] == 2984


def test_self_reference_with_repeated_timestamps_is_refused(datasets, tmp_path):
    log = datasets / "radish-corrected" / "infinite-corridor-corrected.log"
    proc = run("candidates", log, "--reference", log, "--out", tmp_path / "e.jsonl")
    line = one_line_error(proc, 1)
    assert "timestamps repeat" in line and "ambiguous" in line
    assert not (tmp_path / "e.jsonl").exists()


def test_info_does_not_print_broken_durations(datasets):
    for name in ("infinite-corridor-corrected.log", "csail-corrected.log"):
        out = run("info", datasets / "radish-corrected" / name).stdout
        assert "unknown (timestamps repeat or jump)" in out
        summary = json.loads(run("info", datasets / "radish-corrected" / name, "--json").stdout)
        assert summary["duration_s"] is None
    out = run("info", datasets / "intel" / "intel.clf").stdout
    assert "2691.3 s" in out


def test_skip_bad_lines_names_the_lines(tmp_path):
    bad = tmp_path / "bad.log"
    good = "FLASER 3 1 1 1 0 0 0 0 0 0 {t} h {t}"
    bad.write_text(
        "\n".join([good.format(t=1), "FLASER 3 1 inf 1 0 0 0 0 0 0 2 h 2", good.format(t=3)])
        + "\nFLASER 3 1\n"
    )
    proc = run("info", bad, "--skip-bad-lines")
    assert proc.returncode == 0
    assert "skipped 2 malformed line(s) (lines 2, 4)" in proc.stderr


def test_candidates_without_reference_says_so_and_edges_find_their_log(datasets, tmp_path):
    # Run from the log's folder with a relative path, then draw from another folder.
    work = tmp_path / "logs"
    work.mkdir()
    shutil.copy(datasets / "intel" / "intel.gfs.log", work / "intel.gfs.log")
    proc = run(
        "candidates",
        "intel.gfs.log",
        "--poses",
        "odometry",
        "--out",
        "e.jsonl",
        "--max",
        "5",
        "--no-sequential",
        cwd=work,
    )
    assert proc.returncode == 0, proc.stderr
    assert "no reference poses found" in proc.stderr and "unlabelled" in proc.stderr
    edges = [json.loads(line) for line in (work / "e.jsonl").read_text().splitlines()]
    assert all(e["label"] is None for e in edges)
    assert Path(edges[0]["log_path"]).is_absolute()
    png = tmp_path / "edge.png"
    drawn = run("vgm", work / "e.jsonl", "--edge", edges[0]["edge_id"], "--png", png, cwd=REPO)
    assert drawn.returncode == 0, drawn.stderr
    assert cv2.imread(str(png)) is not None


def test_gmapping_reference_with_offset_labels_sequential_edges(datasets, tmp_path):
    out = tmp_path / "e.jsonl"
    proc = run(
        "candidates",
        datasets / "intel" / "intel.clf",
        "--reference",
        datasets / "intel" / "intel.gfs.log",
        "--time-offset",
        "976052857.33753",
        "--no-loops",
        "--out",
        out,
    )
    assert proc.returncode == 0, proc.stderr
    assert "910 of 13631 scans joined" in proc.stderr
    edges = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(edges) == 909
    labels = [e["label"] for e in edges]
    assert labels.count("success") > 0.8 * len(edges)
    assert labels.count("failure") < 0.05 * len(edges)


def test_relations_cut_by_max_are_counted(datasets, tmp_path):
    proc = run(
        "candidates",
        datasets / "intel" / "intel.clf",
        "--reference",
        datasets / "intel" / "intel.relations",
        "--no-sequential",
        "--max",
        "20",
        "--out",
        tmp_path / "e.jsonl",
    )
    assert proc.returncode == 0, proc.stderr
    assert "kept 20 of" in proc.stderr and "relations" in proc.stderr


def test_help_names_arguments_plainly():
    out = " ".join(run("candidates", "--help").stdout.split())
    assert "LOG" in out and "{log}" not in out
    assert "[default: (the log's own poses)]" in out
    info = " ".join(run("info", "--help").stdout.split())
    assert "relations file" in info
    assert "EDGES.jsonl" in run("vgm", "--help").stdout


def test_failure_picture_shows_the_reference_ghost_and_guess_error(tmp_path):
    from vgm_studio.matching.edges import Edge
    from vgm_studio.vgm.picture import edge_caption, edge_picture

    log = tmp_path / "pair.log"
    ranges = " ".join(f"{2 + 0.5 * np.sin(i / 7):.3f}" for i in range(181))
    log.write_text("\n".join(f"FLASER 181 {ranges} 0 0 0 0 0 0 {t} h {t}" for t in (1, 2)) + "\n")
    edge = Edge(
        edge_id="e1",
        log_path=str(log),
        log_sha256="",
        a=0,
        b=1,
        timestamp_a=1,
        timestamp_b=2,
        kind="loop",
        guess=[0.5, 0.0, 0.0],
        estimate=[1.0, 0.0, 0.0],
        match={
            "inlier_ratio": 0.12,
            "residual": 0.03,
            "iterations": 4,
            "converged": True,
            "kiss_moved": 0.0,
        },
        reference=[0.0, 0.0, 0.0],
        label="failure",
    )

    def grey_pixels(img: np.ndarray) -> int:
        return int((np.abs(img.astype(int) - GHOST_BGR.astype(int)).sum(axis=2) < 10).sum())

    with_ref = grey_pixels(edge_picture(edge, tmp_path / "e.png"))
    caption = edge_caption(edge, use_guess=True)
    assert caption.headline is not None and "inliers 12%" in caption.headline
    assert "initial guess vs reference: 50.0 cm" in "\n".join(caption.lines)
    assert "match estimate vs reference: 100.0 cm" in "\n".join(edge_caption(edge, False).lines)
    no_ref = edge_picture(
        Edge(**{**edge.__dict__, "reference": None, "label": None}), tmp_path / "n.png"
    )
    # The ghost (181 points, a metre from where the estimate put them) adds grey pixels.
    assert with_ref > grey_pixels(no_ref) + 100
