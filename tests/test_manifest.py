"""The fleet manifest: JSONL lines checked before anything runs, one line per error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vgm_studio.datasets.manifest import read_manifest
from vgm_studio.errors import InputError
from vgm_studio.tools import cmd


def test_paths_are_read_from_the_manifest_folder_and_names_default_to_the_file(tmp_path):
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "a.clf").write_text("")
    (tmp_path / "a.relations").write_text("")
    manifest = tmp_path / "fleet.jsonl"
    manifest.write_text(
        "# robot 7\n\n"
        + json.dumps({"log": "logs/a.clf", "relations": "a.relations"})
        + "\n"
        + json.dumps({"log": str(tmp_path / "logs" / "a.clf"), "name": "again"})
        + "\n"
    )
    first, second = read_manifest(manifest)
    assert (first.name, first.log, first.relations, first.line) == (
        "a.clf",
        tmp_path / "logs" / "a.clf",
        tmp_path / "a.relations",
        3,
    )
    assert second.name == "again" and second.reference is None


def test_every_bad_line_is_named_once(tmp_path):
    (tmp_path / "a.clf").write_text("")
    manifest = tmp_path / "fleet.jsonl"
    manifest.write_text(
        "\n".join(
            [
                json.dumps({"log": "a.clf"}),
                "{not json",
                json.dumps({"log": "missing.clf"}),
                json.dumps({"reference": "a.clf"}),
                json.dumps({"log": "a.clf", "colour": "red"}),
                json.dumps({"log": "a.clf"}),
                json.dumps(["a.clf"]),
                json.dumps({"log": "a.clf", "name": "../up"}),
            ]
        )
        + "\n"
    )
    with pytest.raises(InputError) as info:
        read_manifest(manifest)
    lines = str(info.value).splitlines()
    assert [line.split(": ", 1)[0] for line in lines] == [f"{manifest}:{n}" for n in range(2, 9)]
    assert "not JSON" in lines[0] and "no such file 'missing.clf'" in lines[1]
    assert 'no "log"' in lines[2] and "unknown field(s) colour" in lines[3]
    assert "taken by line 1" in lines[4] and "not a JSON object" in lines[5]
    assert "names a folder" in lines[6]


def test_the_command_stops_on_a_bad_manifest_before_ray_starts(tmp_path, capsys):
    manifest = tmp_path / "fleet.jsonl"
    manifest.write_text("# nothing yet\n")
    with pytest.raises(SystemExit) as info:
        cmd.main(["fleet", str(manifest), "--out", str(tmp_path / "out")])
    assert info.value.code == 1
    err = capsys.readouterr().err.strip()
    assert err == f"vgm-studio: error: {manifest}: lists no log (one JSON object per line, " + (
        '{"log": "PATH"})'
    )
    assert not Path(tmp_path / "out" / "fleet.parquet").exists()
