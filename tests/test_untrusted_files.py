"""Every payload class of issue 13 that a reader meets: one line naming file, line and field."""

from __future__ import annotations

import csv
import json
import math
import sqlite3

import numpy as np
import pytest

from benchmarks.studio_browser import free_port
from tests.test_cli_checks import one_line_error, run
from tests.untrusted import label_row, make_edges, write_jsonl, write_log
from vgm_studio.datasets import open_log
from vgm_studio.datasets.carmen import format_robotlaser
from vgm_studio.datasets.relations import read_relations
from vgm_studio.errors import InputError
from vgm_studio.labels import LabelStore
from vgm_studio.labels.transfer import export_labels, import_labels
from vgm_studio.matching.edges import read_edges


def _edge_line(tmp_path, **changes):
    obj = make_edges(write_log(tmp_path))[0].to_json()
    obj.update(changes)
    return json.dumps(obj)


def _read_bad_edges(tmp_path, text: str) -> str:
    good = _edge_line(tmp_path)
    path = tmp_path / "edges.jsonl"
    path.write_text(good + "\n" + text + "\n")
    with pytest.raises(InputError) as err:
        read_edges(path)
    message = str(err.value)
    assert message.startswith(f"{path}:2: "), message
    return message.removeprefix(f"{path}:2: ")


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        ({"match": "x"}, "match: Input should be a valid dictionary"),
        ({"params": 1}, "params: Input should be a valid dictionary"),
        ({"a": -1}, "a: Input should be greater than or equal to 0"),
        ({"b": "seven"}, "b: Input should be a valid integer"),
        ({"guess": [0, 0, 1e9]}, "guess: Value error, must be [x, y, theta]"),
        ({"edge_id": "\ud800"}, "edge_id: Input should be a valid string, unable to parse"),
        ({"log_path": "x" * 5000}, "log_path: String should have at most 4096 characters"),
        ({"params": {"read": {"poses": 5}}}, "params.read.poses: Input should be"),
        ({"match": {"inlier_ratio": 7}}, "match.inlier_ratio: Input should be less than"),
        ({"timestamp_a": "soon"}, "timestamp_a: Input should be a valid number"),
    ],
)
def test_edges_of_wrong_types_and_ranges_name_the_field(tmp_path, changes, expected):
    message = _read_bad_edges(tmp_path, _edge_line(tmp_path, **changes))
    assert message.replace("Value error, ", "").startswith(expected.replace("Value error, ", ""))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('{"a": Infinity}', "Infinity is not a JSON number"),
        ('{"a": NaN}', "NaN is not a JSON number"),
        ("[" * 200_000 + "]" * 200_000, "nested deeper than"),
        ('{"a": ' + "7" * 5000 + "}", "an integer too long"),
        ("[" * 40 + "]" * 40, "nested deeper than"),
    ],
)
def test_json_python_would_choke_on_is_one_line(tmp_path, text, expected):
    assert expected in _read_bad_edges(tmp_path, text)


def test_an_export_round_trips_and_its_csv_runs_no_formula(tmp_path):
    log = write_log(tmp_path)
    store = LabelStore(tmp_path / "ws")
    store.add_edges(make_edges(log))
    notes = ['=HYPERLINK("http://x","y")', "=1+2", "+1", "-2+3", "@SUM(A1)", "\tx", "\rx", "'q"]
    ids = store.edge_ids()
    for i, note in enumerate(notes):
        store.label(ids[i % len(ids)], f"=ann{i}", "success", note=note)
    out = tmp_path / "labels.csv"
    export_labels(store, out)
    with out.open(newline="") as f:
        cells = [c for row in csv.reader(f) for c in row]
    assert not any(c.startswith(("=", "+", "-", "@", "\t", "\r")) for c in cells)
    fresh = LabelStore(tmp_path / "fresh")
    import_labels(fresh, out)
    assert [(r.annotator, r.note) for r in fresh.labels()] == [
        (r.annotator, r.note) for r in store.labels()
    ]
    jsonl = tmp_path / "labels.jsonl"
    export_labels(store, jsonl)
    assert {json.loads(x)["note"] for x in jsonl.read_text().splitlines()} <= set(notes)


def _csv_with(tmp_path, column: str, value: str):
    log = write_log(tmp_path)
    store = LabelStore(tmp_path / "ws")
    store.add_edges(make_edges(log))
    store.label(store.edge_ids()[0], "ana", "success")
    out = tmp_path / "labels.csv"
    export_labels(store, out)
    rows = list(csv.DictReader(out.open(newline="")))
    rows[0][column] = value
    with out.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return out


@pytest.mark.parametrize(
    ("column", "value", "expected"),
    [
        ("timestamp_a", "null", ":2: timestamp_a: Input should be a valid number"),
        ("note", "n" * 131_073, ":2: not CSV we read (field larger than field limit"),
        ("labeled_at", "2026-01-01T12:00:00", ":2: labeled_at: has no time zone"),
        ("a", "9" * 5000, ":2: a: Unable to parse input string as an integer"),
        ("guess", "[" * 100, ":2: not JSON"),
    ],
)
def test_bad_csv_cells_are_one_line(tmp_path, column, value, expected):
    path = _csv_with(tmp_path, column, value)
    fresh = LabelStore(tmp_path / "fresh")
    with pytest.raises(InputError) as err:
        import_labels(fresh, path)
    assert str(err.value).startswith(f"{path}{expected}"), str(err.value)
    assert fresh.count_edges() == 0 and fresh.labels() == []


def test_a_refused_import_changes_nothing(tmp_path):
    edges = make_edges(write_log(tmp_path))
    path = write_jsonl(
        tmp_path / "l.jsonl",
        [label_row(edges[0]), label_row(edges[1]), label_row(edges[2], note="\ud800")],
    )
    store = LabelStore(tmp_path / "ws")
    with pytest.raises(InputError, match=r"l.jsonl:3: note: Input should be a valid string"):
        import_labels(store, path)
    assert store.count_edges() == 0 and store.labels() == [] and store.history() == []


def test_a_failure_while_writing_rolls_the_whole_import_back(tmp_path):
    edges = make_edges(write_log(tmp_path))
    rows = [label_row(edges[0]), label_row(edges[1]), label_row(edges[2], annotator="zed")]
    path = write_jsonl(tmp_path / "l.jsonl", rows)
    store = LabelStore(tmp_path / "ws")
    # A real SQLite trigger, put in the file by a second connection, makes the third label's
    # write fail, after two edges and labels.
    with sqlite3.connect(store.path) as other:
        other.execute(
            "CREATE TRIGGER boom BEFORE INSERT ON labels WHEN NEW.annotator = 'zed' "
            "BEGIN SELECT RAISE(ABORT, 'boom'); END"
        )
    other.close()
    with pytest.raises(Exception, match="boom"):
        import_labels(store, path)
    assert store.count_edges() == 0 and store.labels() == [] and store.history() == []


def test_the_newer_label_wins_as_an_instant_not_as_text(tmp_path):
    edges = make_edges(write_log(tmp_path))
    store = LabelStore(tmp_path / "ws")
    first = write_jsonl(
        tmp_path / "a.jsonl", [label_row(edges[0], labeled_at="2026-01-01T12:00:00+00:00")]
    )
    import_labels(store, first)
    # 13:00+05:00 is 08:00 UTC: older, though it sorts later as text.
    older = write_jsonl(
        tmp_path / "b.jsonl",
        [label_row(edges[0], label="failure", labeled_at="2026-01-01T13:00:00+05:00")],
    )
    assert import_labels(store, older) == (0, 0)
    newer = write_jsonl(
        tmp_path / "c.jsonl",
        [label_row(edges[0], label="failure", labeled_at="2026-01-01T12:30:00+00:00")],
    )
    assert import_labels(store, newer) == (0, 1)
    assert store.labels()[0].label == "failure"


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"b": 99}, ":1: b: scan 99 is past the end of its log (6 scans)"),
        ({"log_path": "/nowhere/x.log"}, ":1: log_path: /nowhere/x.log: log of edge"),
        ({"log_sha256": "ab" * 32}, "sha256 mismatch"),
        ({"log_path": "/proc/self/environ"}, "sha256 mismatch"),
        ({"log_sha256": ""}, ":1: log_sha256: missing; the studio reads only a log whose"),
    ],
)
def test_edges_the_studio_cannot_show_are_refused_by_import_and_label(tmp_path, change, expected):
    edge = make_edges(write_log(tmp_path))[0]
    labels = write_jsonl(tmp_path / "l.jsonl", [label_row(edge, **change)])
    store = LabelStore(tmp_path / "ws")
    with pytest.raises(InputError) as err:
        import_labels(store, labels)
    assert expected in str(err.value)
    assert store.count_edges() == 0
    edges = write_jsonl(tmp_path / "e.jsonl", [{**edge.to_json(), **change}])
    port = free_port()
    line = one_line_error(run("label", edges, "--workspace", tmp_path / "w2", "--port", port), 1)
    assert line.startswith(f"vgm-studio: error: {edges}:1: ")
    assert expected.split(":1: ")[-1] in line
    # Nothing of the file named by log_path reaches a message.
    for value in ("PATH=", "HOME="):
        assert value not in line and value not in str(err.value)


def _flaser(ranges: str, t: str = "5", pose: str = "0 0 0 0 0 0") -> str:
    return f"FLASER {len(ranges.split())} {ranges} {pose} {t} h {t}"


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("FLASER 3 1 1 1 1 0 0 0 0 0 0 5 h 5", "it declares 3 readings, so the line should"),
        ("FLASER 4 1 1 1 0 0 0 0 0 0 5 h 5", "it declares 4 readings"),
        (_flaser("1 1 1", t="inf"), "timestamp (field 11) must be a finite number"),
        (_flaser("1 4e38 1"), "range 2 (field 3) is '4e38'"),
        ("FLASER " + "9" * 5000 + " 1", "is not a beam count"),
        ("FLASER", "expected at least 2 fields (the count in field 1), found 1"),
        (_flaser("1 1 1", pose="1e300 0 0 0 0 0"), "pose (fields 5..6) is over 1e+07 m"),
    ],
)
def test_carmen_lines_that_disagree_or_overflow_are_refused(tmp_path, line, expected):
    good = _flaser("1 1 1", t="1")
    path = tmp_path / "t.log"
    path.write_text(f"{good}\n{line}\n")
    with pytest.raises(InputError) as err:
        open_log(path)
    assert str(err.value).startswith(f"{path}:2: ") and expected in str(err.value)


def test_robotlaser_infinite_resolution_is_refused(tmp_path):
    line = format_robotlaser(
        [1.0, 2.0], angle_min=-1, angle_increment=1, max_range=30, laser_pose=(0, 0, 0), timestamp=5
    ).split()
    line[4] = "inf"
    path = tmp_path / "t.log"
    path.write_text(" ".join(line) + "\n")
    with pytest.raises(InputError, match=r"t.log:1: ROBOTLASER1: resolution \(field 4\) must be"):
        open_log(path)


def test_messages_quote_a_few_sanitised_characters_of_a_bad_token(tmp_path):
    path = tmp_path / "t.log"
    token = "\x1b[31mred\x00" + "s" * 100
    path.write_text(_flaser("1 1 1") + "\n" + _flaser(f"1 {token} 1") + "\n")
    with pytest.raises(InputError) as err:
        open_log(path)
    message = str(err.value)
    assert "\x1b" not in message and "\x00" not in message and "s" * 13 not in message
    assert "'?[31mred?sss…'" in message
    junk = tmp_path / "junk.log"
    junk.write_text("\x1b]0;owned\x07 1 2\nSECRET=hunter2hunter2 x\n")
    with pytest.raises(InputError) as err:
        open_log(junk)
    assert "\x1b" not in str(err.value) and "hunter" not in str(err.value)
    assert str(err.value).endswith("no FLASER/ROBOTLASER1 scans in this log (found 2 other lines)")


def test_a_huge_reading_keeps_the_range_finite_and_info_json_standard(tmp_path):
    path = tmp_path / "t.log"
    path.write_text("\n".join(_flaser(f"1 {r} 1", t=str(i)) for i, r in enumerate([2, 3e38])))
    log = open_log(path)
    assert all(math.isfinite(s.max_range) for s in log.scans)
    proc = run("info", path, "--json")
    assert proc.returncode == 0, proc.stderr

    def refuse(name):
        raise AssertionError(f"non-standard JSON {name}")

    summary = json.loads(proc.stdout, parse_constant=refuse)
    assert np.isfinite(summary["max_range"]).all()


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"1 2 0 0 0 0 0 0\n\xff\xfe 1 2\n", "not a text relations file"),
        (b"1 2 nan 0 0 0 0 0\n", ":1: x: not a finite number"),
        (b"1 inf 0 0 0 0 0 inf\n", ":1: t2, yaw: not a finite number"),
    ],
)
def test_relations_refuse_bytes_and_non_finite_poses(tmp_path, content, expected):
    path = tmp_path / "r.relations"
    path.write_bytes(content)
    with pytest.raises(InputError) as err:
        read_relations(path)
    assert str(err.value).startswith(str(path)) and expected in str(err.value)
    log = write_log(tmp_path)
    line = one_line_error(run("candidates", log, "--reference", path, "--out", tmp_path / "e"), 1)
    assert expected in line
