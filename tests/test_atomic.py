"""Files written whole or not at all (``vgm_studio.atomic``), the one writer every file
format of the project goes through: edges, checkpoints, resume states, exports, fleet tables."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap

import pytest

from vgm_studio.atomic import atomic_path, write_text_atomically


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_clean_write_replaces_the_file_with_a_plain_files_mode_and_leaves_nothing_beside(
    tmp_path,
):
    target = tmp_path / "sub" / "edges.jsonl"  # a missing folder is made
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp.exists() and not target.exists()
        assert not tmp.name.endswith(".jsonl"), "a *.jsonl scan must not take it for a file"
        tmp.write_text("first\n")
    write_text_atomically(target, "second\n")
    assert target.read_text() == "second\n"
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~_umask()
    assert [p.name for p in target.parent.iterdir()] == ["edges.jsonl"]


def test_a_failed_write_keeps_the_old_file_and_removes_its_temporary(tmp_path):
    target = tmp_path / "model.pt"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="disk full"), atomic_path(target) as tmp:
        tmp.write_text("half of the ne")
        raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]


def test_a_folder_in_the_way_raises_oserror_and_leaves_no_temporary(tmp_path):
    (tmp_path / "out.csv").mkdir()
    with pytest.raises(OSError):
        write_text_atomically(tmp_path / "out.csv", "a,b\r\n", newline="")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_a_file_where_the_folder_should_be_says_so(tmp_path):
    (tmp_path / "out").write_text("not a folder")
    for target in (tmp_path / "out" / "labels.csv", tmp_path / "out" / "sub" / "labels.csv"):
        with pytest.raises(NotADirectoryError) as raised:
            write_text_atomically(target, "a,b\r\n")
        assert raised.value.strerror == f"{tmp_path / 'out'} is a file, not a folder"
    assert (tmp_path / "out").read_text() == "not a folder"


def test_two_writers_of_one_file_never_share_a_temporary_and_the_last_wins_whole(tmp_path):
    target = tmp_path / "row.json"
    with atomic_path(target) as first, atomic_path(target) as second:
        assert first != second
        first.write_text("A" * 10_000)
        second.write_text("B" * 10)
    # second exits first, then first replaces it: one whole file, never a mix
    assert target.read_text() == "A" * 10_000


def test_a_writer_killed_mid_write_leaves_the_old_file_whole(tmp_path):
    target = tmp_path / "state.pt"
    target.write_text("the last whole state")
    script = textwrap.dedent(
        f"""
        import os, signal
        from vgm_studio.atomic import atomic_path
        with atomic_path({str(target)!r}) as tmp:
            with open(tmp, "w") as f:
                f.write("half")
                f.flush()
            os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert run.returncode == -signal.SIGKILL, run.stderr
    assert target.read_text() == "the last whole state"
