"""The studio's commands: bad input stops before the server starts; labels go out and back in."""

from __future__ import annotations

import re
import socket
import sqlite3
import subprocess
import sys
import time
from collections import Counter

import pytest

from benchmarks.studio_browser import free_port
from tests.test_cli_checks import one_line_error, run
from vgm_studio import __version__
from vgm_studio.labels import LabelStore
from vgm_studio.matching.edges import read_edges, write_edges


def test_port_in_use_is_refused_before_serving(office_edges, tmp_path):
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        proc = run("label", office_edges, "--workspace", tmp_path / "ws", "--port", port)
    line = one_line_error(proc, 1)
    assert f"127.0.0.1:{port}: cannot listen: the port is in use" in line
    assert not (tmp_path / "ws").exists()  # nothing made for a server that never ran


# Runs the command line, then says on stdout which slow modules it had imported.
_IMPORTED_AT_EXIT = """
import atexit, sys
heavy = ("torch", "viser", "scipy")
atexit.register(lambda: print("imported:", *[m for m in heavy if m in sys.modules]))
from vgm_studio.tools.cmd import main
sys.argv[0] = "vgm-studio"
main()
"""


@pytest.mark.parametrize("command", ["label", "demo"])
def test_a_port_in_use_is_refused_before_the_slow_start_up(command, office_edges, tmp_path):
    """The port is checked before torch, viser and scipy load (7.7 s on a cold machine)."""
    source = [str(office_edges)] if command == "label" else []
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        args = [command, *source, "--workspace", str(tmp_path / "ws"), "--port", str(port)]
        proc = subprocess.run(
            [sys.executable, "-c", _IMPORTED_AT_EXIT, *args],
            capture_output=True,
            text=True,
            timeout=120,
        )
    line = one_line_error(proc, 1)
    assert f"127.0.0.1:{port}: cannot listen: the port is in use" in line
    assert proc.stdout.strip() == "imported:", proc.stdout


def test_missing_and_corrupt_sources_name_file_and_line(office_edges, tmp_path):
    port = str(free_port())
    missing = tmp_path / "nope.log"
    line = one_line_error(run("label", missing, "--workspace", tmp_path / "ws", "--port", port), 1)
    assert line.endswith(f"{missing}: no such file or folder")
    bad = tmp_path / "bad.jsonl"
    lines = office_edges.read_text().splitlines()
    bad.write_text("\n".join([lines[0], lines[1][:40], *lines[2:5]]) + "\n")
    line = one_line_error(run("label", bad, "--workspace", tmp_path / "ws2", "--port", port), 1)
    assert f"{bad}:2: not JSON" in line


def test_a_workspace_of_another_version_is_refused(office_edges, tmp_path):
    LabelStore(tmp_path / "ws").close()
    db = sqlite3.connect(tmp_path / "ws" / "labels.sqlite")
    db.execute("UPDATE meta SET value = '7' WHERE key = 'schema'")
    db.commit()
    db.close()
    proc = run("label", office_edges, "--workspace", tmp_path / "ws", "--port", free_port())
    assert "schema 7" in one_line_error(proc, 1)


def test_export_import_commands_round_trip(office_edges, tmp_path):
    store = LabelStore(tmp_path / "ws")
    store.add_edges(read_edges(office_edges))
    ids = store.edge_ids()
    store.label(ids[0], "ana", "success")
    store.label(ids[4], "ben", "failure", note="door pitch")
    store.close()
    out = tmp_path / "labels.csv"
    proc = run("export", "--workspace", tmp_path / "ws", "--out", out)
    assert proc.returncode == 0 and "wrote 2 labels" in proc.stdout
    proc = run("import", out, "--workspace", tmp_path / "other")
    assert proc.returncode == 0, proc.stderr
    assert "2 labels added or updated, 2 new edges" in proc.stdout
    assert LabelStore(tmp_path / "other").labels() == LabelStore(tmp_path / "ws").labels()
    line = one_line_error(run("export", "--workspace", tmp_path / "ws", "--out", "x.txt"), 1)
    assert "unknown label file type '.txt'" in line
    line = one_line_error(run("export", "--workspace", tmp_path / "none", "--out", out), 1)
    assert "no workspace here" in line


@pytest.mark.long
@pytest.mark.slow
def test_demo_prepares_its_workspace_with_predictions(tmp_path):
    proc = run("demo", "--workspace", tmp_path / "demo", "--no-serve")
    assert proc.returncode == 0, proc.stderr
    store = LabelStore(tmp_path / "demo")
    assert store.count_edges() == 977
    preds = store.predictions()
    assert preds.model is not None and preds.model.startswith("vgmnet-default.pt:")
    assert len(preds.p) == 977 and 0.0 < min(preds.p.values()) < max(preds.p.values()) < 1.0
    again = run("demo", "--workspace", tmp_path / "demo", "--no-serve")
    assert again.returncode == 0 and "977 edges" in again.stdout


@pytest.mark.long
def test_ready_counts_from_the_process_start(tmp_path):
    """The studio's "ready N s after start" is the wait a user sees: the interpreter's
    start, the imports and the server's start included (it said 0.0 s on a prepared
    workspace)."""
    assert run("demo", "--workspace", tmp_path / "demo", "--no-serve").returncode == 0
    began = time.perf_counter()
    lines = _served_says(
        "demo", "--workspace", tmp_path / "demo", "--port", free_port(), "--no-trainer"
    )
    waited = time.perf_counter() - began
    said = re.search(r"ready (\d+\.\d) s after start", lines[-1])
    assert said is not None, lines
    assert 0.3 < float(said.group(1)) <= waited + 0.1


def _served_says(*args: object) -> list[str]:
    """What ``vgm-studio ARGS`` prints until it serves; the server is then stopped."""
    cmd = [sys.executable, "-m", "vgm_studio.tools.cmd", *map(str, args)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            if line.startswith("VGM Studio:"):
                break
    finally:
        proc.kill()
        proc.wait(timeout=30)
    return lines


def test_label_into_an_existing_workspace_says_what_it_added(office_edges, tmp_path):
    edges = read_edges(office_edges)
    first, second = tmp_path / "first.jsonl", tmp_path / "second.jsonl"
    write_edges(first, edges[:10])
    write_edges(second, edges[5:30])
    ws = tmp_path / "ws"
    common = ["--workspace", ws, "--no-model", "--no-trainer"]
    said = _served_says("label", first, *common, "--port", free_port())
    assert not any("added" in line for line in said)  # a new workspace: nothing to tell
    said = _served_says("label", second, *common, "--port", free_port())
    kinds = Counter(e.kind for e in edges[10:30])
    which = ", ".join(f"{n} {kind}" for kind, n in sorted(kinds.items()))
    assert f"{second}: added 20 edges ({which}) to the 10 in {ws}" in said
    said = _served_says("label", second, *common, "--port", free_port())
    assert any("no edges added" in line for line in said)


def test_off_loopback_the_address_carries_a_token(office_edges, tmp_path):
    args = ["--workspace", tmp_path / "ws", "--no-model", "--no-trainer", "--port", free_port()]
    said = _served_says("label", office_edges, *args, "--host", "0.0.0.0")
    served = next(line for line in said if line.startswith("VGM Studio:"))
    assert re.search(r"http://localhost:\d+/[A-Za-z0-9_-]{16,}", served)
    proc = run("label", office_edges, *args, "--token", "a b")
    assert "--token" in one_line_error(proc, 2)


def test_version_and_agreement_commands(office_edges, tmp_path):
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"vgm-studio {__version__}"
    store = LabelStore(tmp_path / "ws")
    store.add_edges(read_edges(office_edges))
    ids = store.edge_ids()
    for i, edge in enumerate(ids[:6]):
        store.label(edge, "ana", "success" if i % 2 else "failure")
        store.label(edge, "bob", "success" if i < 3 else "failure")
    store.close()
    proc = run("agreement", "--workspace", tmp_path / "ws")
    assert proc.returncode == 0, proc.stderr
    header, row = proc.stdout.strip().splitlines()
    assert "Cohen's kappa" in header
    assert row.split()[:5] == ["ana", "·", "bob", "6", "2"]  # ana and bob agree on 2 of 6
    proc = run("agreement", "--workspace", tmp_path / "none")
    one_line_error(proc, 1)
