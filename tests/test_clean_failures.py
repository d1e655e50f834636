"""A command that fails on its input leaves nothing behind, and never harms what was there."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.untrusted import seed_files
from vgm_studio.labels import LabelStore
from vgm_studio.labels.opening import store_to_fill


def run(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("vgm-studio")
    cmd = [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]
    return subprocess.run(
        [*cmd, *map(str, args)], capture_output=True, text=True, timeout=300, cwd=cwd
    )


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def one_line_error(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.fixture
def seeds(tmp_path: Path) -> dict[str, Path]:
    folder = tmp_path / "seeds"
    folder.mkdir()
    return seed_files(folder)


def test_a_typod_log_makes_no_workspace(tmp_path: Path) -> None:
    work = tmp_path / "work"
    work.mkdir()
    proc = run("label", "intel.clff", "--no-trainer", "--port", free_port(), cwd=work)
    assert one_line_error(proc) == "vgm-studio: error: intel.clff: no such file or folder"
    assert listing(work) == []  # no intel.studio/labels.sqlite


def test_a_typod_reference_makes_no_workspace(tmp_path: Path, seeds: dict[str, Path]) -> None:
    work = tmp_path / "work"
    work.mkdir()
    proc = run(
        "label", seeds["log"], "--reference", "ref.relatons", "--port", free_port(), cwd=work
    )
    assert "ref.relatons: no such reference file" in one_line_error(proc)
    assert listing(work) == []


def test_a_bad_import_makes_no_workspace(tmp_path: Path, seeds: dict[str, Path]) -> None:
    work = tmp_path / "work"
    work.mkdir()
    (work / "bad.jsonl").write_text('{"x": 1}\n')
    proc = run("import", "bad.jsonl", "--workspace", "t.studio", cwd=work)
    assert one_line_error(proc).endswith("bad.jsonl:1: annotator: missing")
    # A good file before the bad one is not written either: every file is checked first.
    proc = run("import", seeds["labels.jsonl"], "bad.jsonl", "--workspace", "t.studio", cwd=work)
    one_line_error(proc)
    assert listing(work) == ["bad.jsonl"]


def test_a_log_that_fails_on_reading_leaves_no_folders(tmp_path: Path) -> None:
    work = tmp_path / "work"
    work.mkdir()
    (work / "robot.log").write_text("this is no CARMEN log\n")
    proc = run("label", "robot.log", "--no-trainer", "--port", free_port(), cwd=work)
    one_line_error(proc)
    # A bad edges file is found only while the workspace is filled: the folders made for
    # it (parents included) go again.
    (work / "edges.jsonl").write_text('{"edge_id": 1}\n')
    proc = run(
        "label", "edges.jsonl", "--workspace", "a/b/c.studio", "--port", free_port(), cwd=work
    )
    one_line_error(proc)
    assert listing(work) == ["edges.jsonl", "robot.log"]


def test_a_failure_keeps_the_workspace_that_was_there(
    tmp_path: Path, seeds: dict[str, Path]
) -> None:
    work = tmp_path / "work"
    work.mkdir()
    good = run("import", seeds["labels.jsonl"], "--workspace", "new/t.studio", cwd=work)
    assert good.returncode == 0, good.stderr
    assert "6 labels added or updated, 3 new edges" in good.stdout
    before = listing(work)
    (work / "edges.jsonl").write_text('{"edge_id": 1}\n')
    proc = run(
        "label", "edges.jsonl", "--workspace", "new/t.studio", "--port", free_port(), cwd=work
    )
    one_line_error(proc)
    assert listing(work) == sorted([*before, "edges.jsonl"])
    store = LabelStore(work / "new" / "t.studio", create=False)
    assert len(store.labels()) == 6
    store.close()


def test_store_to_fill_removes_only_what_it_made(tmp_path: Path) -> None:
    made = tmp_path / "x" / "y" / "w.studio"
    with pytest.raises(KeyboardInterrupt), store_to_fill(made):
        assert (made / "labels.sqlite").exists()
        raise KeyboardInterrupt  # Ctrl-C while the first candidates are made
    assert not (tmp_path / "x").exists()

    kept = tmp_path / "kept.studio"
    LabelStore(kept).close()
    with pytest.raises(ValueError), store_to_fill(kept):
        raise ValueError
    assert (kept / "labels.sqlite").exists()

    with store_to_fill(made) as store:  # success: the store stays, open
        store.add_edges([])
    assert store.count_edges() == 0
    store.close()
    assert (made / "labels.sqlite").exists()
