"""Edges: stable ids, JSONL round trip, malformed files, reference labels."""

from __future__ import annotations

import json
import math

import pytest

from vgm_studio.errors import InputError
from vgm_studio.matching.edges import Edge, edge_id, read_edges, write_edges
from vgm_studio.matching.reference_labels import LabelThresholds, reference_label


def make_edge(**kw) -> Edge:
    base = dict(
        edge_id="e1",
        log_path="x.log",
        log_sha256="abc",
        a=1,
        b=60,
        timestamp_a=1.0,
        timestamp_b=float("nan"),
        kind="loop",
        guess=[0.1, 0.2, 0.3],
        estimate=[0.0, 0.0, 0.0],
        match={"inlier_ratio": 0.8},
        reference=None,
        label=None,
        params={"candidates": {"seed": 0}},
    )
    base.update(kw)
    return Edge(**base)


def test_edge_id_is_stable_and_sensitive():
    ida = edge_id("h", 1, 2, [0.1, 0.2, 0.3])
    assert ida == edge_id("h", 1, 2, [0.1 + 1e-9, 0.2, 0.3])
    assert ida != edge_id("h", 1, 3, [0.1, 0.2, 0.3])
    assert ida != edge_id("h", 1, 2, [0.1, 0.2, 0.31])
    assert ida != edge_id("g", 1, 2, [0.1, 0.2, 0.3])
    assert len(ida) == 16


def test_round_trip(tmp_path):
    edges = [make_edge(), make_edge(edge_id="e2", reference=[1, 2, 3], label="success")]
    path = tmp_path / "out" / "edges.jsonl"
    assert write_edges(path, edges) == 2
    lines = path.read_text().splitlines()
    assert len(lines) == 2 and json.loads(lines[0])["timestamp_b"] is None
    back = read_edges(path)
    assert back[1].reference == [1.0, 2.0, 3.0] and back[1].label == "success"
    assert back[0].params == {"candidates": {"seed": 0}}
    assert math.isnan(back[0].timestamp_b)


def test_writing_onto_a_folder_is_one_line_and_leaves_the_folder_clean(tmp_path):
    folder = tmp_path / "edges.jsonl"
    folder.mkdir()
    with pytest.raises(InputError) as err:
        write_edges(folder, [make_edge()])
    assert str(err.value).startswith(f"{folder}: cannot write")
    assert list(tmp_path.iterdir()) == [folder] and not any(folder.iterdir())


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("{not json", "not JSON"),
        # json says "starting at", and the message adds the column once
        ('{"edge_id": "cut off', r"not JSON \(Unterminated string starting at column 13\)"),
        ('{"edge_id": "x"}', "log_path: missing"),
        ("[1, 2]", "must be a JSON object"),
    ],
)
def test_malformed_edges_name_line(tmp_path, text, message):
    path = tmp_path / "e.jsonl"
    good = json.dumps(make_edge().to_json())
    path.write_text(good + "\n" + text + "\n")
    with pytest.raises(InputError, match=rf"e.jsonl:2: .*{message}"):
        read_edges(path)


def test_bad_field_values(tmp_path):
    path = tmp_path / "e.jsonl"
    for field, value, message in [
        ("kind", "weird", "kind: Input should be 'sequential' or 'loop'"),
        ("label", "maybe", "label: Input should be 'success', 'failure' or 'ambiguous'"),
        ("guess", [1, 2], "three finite numbers"),
    ]:
        obj = make_edge().to_json()
        obj[field] = value
        path.write_text(json.dumps(obj) + "\n")
        with pytest.raises(InputError, match=message):
            read_edges(path)


def test_reference_label_thresholds():
    ref = [1.0, 0.0, 0.0]
    assert reference_label(ref, [1.05, 0.05, math.radians(1.5)]) == "success"
    assert reference_label(ref, [1.2, 0.0, 0.0]) == "ambiguous"
    assert reference_label(ref, [1.0, 0.0, math.radians(3)]) == "ambiguous"
    assert reference_label(ref, [1.31, 0.0, 0.0]) == "failure"
    assert reference_label(ref, [1.0, 0.0, math.radians(5.5)]) == "failure"
    loose = LabelThresholds(success_xy=0.25, success_theta_deg=4)
    assert reference_label(ref, [1.2, 0.0, 0.0], loose) == "success"
    # The error is taken in the reference frame: rotation of the frame matters.
    rotated = [0.0, 0.0, math.pi / 2]
    assert reference_label(rotated, [0.0, 0.05, math.pi / 2]) == "success"


def test_the_edge_schema_reads_every_read_option():
    # Edges record their ReadOptions; a field the schema lacks would refuse new edge files.
    from dataclasses import fields

    from vgm_studio.datasets.options import ReadOptions
    from vgm_studio.matching.edge_schema import ReadParams

    assert set(ReadParams.model_fields) == {f.name for f in fields(ReadOptions)}
