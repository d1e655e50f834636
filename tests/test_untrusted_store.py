"""Damaged, read-only and immutable workspaces, bad paths and hosts: one line, never a traceback."""

from __future__ import annotations

import shutil
import sqlite3
import subprocess
from pathlib import Path

import pytest
import torch

from benchmarks.studio_browser import free_port
from tests.test_cli_checks import one_line_error, run
from tests.untrusted import label_row, make_edges, write_jsonl, write_log
from vgm_studio.labels import LabelStore

REPO = Path(__file__).resolve().parents[1]


def _chattr(flag: str, path: Path) -> None:
    proc = subprocess.run(["chattr", flag, str(path)], capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"chattr {flag} is not allowed here: {proc.stderr.strip()}")


@pytest.fixture
def immutable(request):
    """Makes a path immutable (chattr +i) for the test, and mutable again after it."""
    made: list[Path] = []

    def make(path: Path) -> Path:
        _chattr("+i", path)
        made.append(path)
        return path

    yield make
    for path in made:
        subprocess.run(["chattr", "-i", str(path)], check=False)


@pytest.fixture
def workspace(tmp_path) -> Path:
    store = LabelStore(tmp_path / "ws")
    store.add_edges(make_edges(write_log(tmp_path)))
    store.label(store.edge_ids()[0], "ana", "success")
    store.close()
    return tmp_path / "ws"


def test_a_damaged_page_stops_the_command_and_says_how_to_recover(workspace, tmp_path):
    db = sqlite3.connect(workspace / "labels.sqlite")
    db.execute("PRAGMA journal_mode=DELETE")  # the pages below are in the file, not the WAL
    root = db.execute("SELECT rootpage FROM sqlite_master WHERE name = 'labels'").fetchone()[0]
    size = db.execute("PRAGMA page_size").fetchone()[0]
    db.close()
    data = bytearray((workspace / "labels.sqlite").read_bytes())
    data[(root - 1) * size : root * size] = b"\xff" * size
    (workspace / "labels.sqlite").write_bytes(bytes(data))
    for args in (["export", "--out", tmp_path / "x.jsonl"], ["label", "--port", free_port()]):
        source = [] if args[0] == "export" else [tmp_path / "tiny.log"]
        line = one_line_error(run(args[0], *source, "--workspace", workspace, *args[1:]), 1)
        assert "the label store is damaged" in line and ".recover" in line


def test_a_table_missing_a_column_is_damage(workspace, tmp_path):
    db = sqlite3.connect(workspace / "labels.sqlite")
    db.execute("ALTER TABLE labels DROP COLUMN note")
    db.commit()
    db.close()
    line = one_line_error(run("export", "--workspace", workspace, "--out", tmp_path / "x.csv"), 1)
    assert "damaged (table labels lacks note)" in line


def test_an_immutable_store_is_refused_before_anything_is_written(workspace, tmp_path, immutable):
    labels = write_jsonl(
        tmp_path / "l.jsonl",
        [label_row(make_edges(tmp_path / "tiny.log")[1], labeled_at="2027-01-01T00:00:00Z")],
    )
    immutable(workspace / "labels.sqlite")
    line = one_line_error(run("import", labels, "--workspace", workspace), 1)
    assert "the label store cannot be written" in line and "immutable" in line
    # Reading it still works: export is how its labels leave.
    assert run("export", "--workspace", workspace, "--out", tmp_path / "x.jsonl").returncode == 0


def test_an_immutable_folder_is_one_line_for_a_new_store_and_for_export(
    workspace, tmp_path, immutable
):
    folder = tmp_path / "locked"
    folder.mkdir()
    immutable(folder)
    labels = write_jsonl(tmp_path / "l.jsonl", [label_row(make_edges(tmp_path / "tiny.log")[0])])
    line = one_line_error(run("import", labels, "--workspace", folder / "ws"), 1)
    assert "cannot open the label store" in line and "writable" in line
    line = one_line_error(run("export", "--workspace", workspace, "--out", folder / "x.csv"), 1)
    assert line.endswith(f"{folder / 'x.csv'}: cannot write here (Operation not permitted)")


def test_eval_json_into_a_folder_that_cannot_be_written(office_edges, tmp_path, immutable):
    folder = tmp_path / "locked"
    folder.mkdir()
    immutable(folder)
    model = REPO / "assets" / "models" / "vgmnet-default.pt"
    proc = run("eval", model, office_edges, "--json", folder / "m.json")
    assert one_line_error(proc, 1).endswith(
        f"{folder / 'm.json'}: cannot write here (Operation not permitted)"
    )


def test_a_path_that_is_not_utf8_is_one_line(tmp_path):
    log = write_log(tmp_path)
    odd = tmp_path / "bad\udcff.log"  # the byte 0xff, as Python keeps an undecodable name
    shutil.copy(log, odd)
    for args in (["info", odd], ["label", odd, "--workspace", tmp_path / "ws", "--no-model"]):
        line = one_line_error(
            run(*args, "--port", free_port()) if args[0] == "label" else run(*args), 1
        )
        assert line.endswith("bad\\xff.log: the path is not UTF-8 text; rename it")


def test_a_host_that_is_not_this_machine_says_so(tmp_path):
    log = write_log(tmp_path)
    # 192.0.2.0/24 is TEST-NET-1: documentation only, never a local address.
    line = one_line_error(
        run("label", log, "--host", "192.0.2.7", "--workspace", tmp_path / "w"), 1
    )
    assert "--host 192.0.2.7: is not an address of this machine" in line
    line = one_line_error(run("label", log, "--host", "no-such-host.invalid"), 1)
    assert "is not a name or address that resolves" in line


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"vgm": {"size": "x", "resolution": 0.05, "sigma": 0.02}}, "vgm.size: Input should be"),
        ({"vgm": {"size": 400}}, "vgm.resolution: missing"),
        ({"threshold": float("nan")}, "threshold: must be a finite number"),
        ({"model": "evil"}, "model: unknown model (expected one of vgmnet,"),
        (
            {"context": {"neighbours": -1, "spacing": 0.5, "turn": 0.35, "reach": 2.0, "scans": 9}},
            "context.neighbours: Input should be greater than or equal to 0",
        ),
    ],
)
def test_a_checkpoint_with_bad_metadata_is_one_line(office_edges, tmp_path, change, expected):
    ckpt = torch.load(REPO / "assets" / "models" / "vgmnet-default.pt", weights_only=True)
    ckpt.update(change)
    bad = tmp_path / "bad.pt"
    torch.save(ckpt, bad)
    line = one_line_error(run("eval", bad, office_edges), 1)
    assert f"{bad}: not a usable model checkpoint: {expected}" in line
