"""``vgm-studio audit``: other SLAMs' graphs read (g2o with ROBOTLASER1, g2o with ``--scans``
and ``--vertex-times`` or ``--vertex-index``, TORO), judged, cleaned and written back."""

from __future__ import annotations

import json
from pathlib import Path

import gtsam
import numpy as np
import pytest
from rerun.chunk import RrdReader

from vgm_studio.datasets import open_log
from vgm_studio.datasets.g2o import read_graph
from vgm_studio.datasets.tum import write_tum
from vgm_studio.errors import InputError
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import read_edges
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.tools import cmd


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """The 12 m × 5 m corridor loop, a little over one lap (~380 scans)."""
    return simulate(SimConfig(preset="demo", seed=2, num_beams=181), tmp_path_factory.mktemp("d"))


@pytest.fixture(scope="module")
def graph(demo, tmp_path_factory) -> Path:
    """The graph ``slam`` made of the demo log, as a g2o file that carries its scans."""
    out = tmp_path_factory.mktemp("g") / "after.g2o"
    cmd.main(["slam", str(demo), "--validator", "reference", "--g2o", str(out)])
    return out


@pytest.fixture(scope="module")
def audited(demo, graph, tmp_path_factory) -> Path:
    """The graph audited with five injected false loops, every output written."""
    out = tmp_path_factory.mktemp("a")
    cmd.main(
        [
            "audit", str(graph),
            "--inject-false-loops", "5", "--seed", "3",
            "--reference", str(demo),
            "--json", str(out / "audit.json"),
            "--markdown", str(out / "audit.md"),
            "--g2o", str(out / "clean.g2o"),
            "--edges-out", str(out / "flagged.jsonl"),
            "--record", str(out / "audit.rrd"),
            "--map-png", str(out / "maps"),
        ]
    )  # fmt: skip
    return out


def _doc(folder: Path) -> dict:
    return json.loads((folder / "audit.json").read_text())


def test_injected_false_loops_are_flagged_and_the_graphs_own_edges_kept(audited, graph):
    doc = _doc(audited)
    edges = doc["edges"]
    injected = [e for e in edges if e["injected"]]
    own_loops = [e for e in edges if e["kind"] == "loop" and not e["injected"]]
    assert len(injected) == 5 == doc["injected_false_loops"]
    assert all(e["decision"] == "flagged" for e in injected), [e["reason"] for e in injected]
    assert doc["injected_flagged"] == 5
    # The graph slam kept (validated against the reference) is right: nearly all of it stays.
    assert own_loops, "the demo run closed no loop"
    assert sum(e["decision"] == "flagged" for e in own_loops) <= len(own_loops) // 10
    sequential = [e for e in edges if e["kind"] == "sequential"]
    assert sum(e["decision"] == "flagged" for e in sequential) <= len(sequential) // 20
    vertices = len(read_graph(graph))
    assert doc["vertices"] == vertices and len(sequential) == vertices - 1
    for e in edges:
        assert {"from", "to", "kind", "decision", "reason", "p_success", "injected"} <= set(e)
        assert e["reason"], e
        assert e["decision"] in ("kept", "flagged")


def test_scored_against_the_reference_the_cleaned_graph_undoes_the_injected_damage(audited):
    doc = _doc(audited)
    for key in ("input", "before", "after"):
        assert {"trans_mean", "trans_std", "rot_mean_deg", "rot_std_deg", "n"} <= set(doc[key])
        assert doc[key]["n"] > 50
    # Five false loops bend the graph optimised with every edge; the cleaned one is as good
    # as the graph slam made.
    assert doc["before"]["trans_mean"] > 2 * doc["input"]["trans_mean"]
    assert doc["after"]["trans_mean"] <= 1.1 * doc["input"]["trans_mean"] + 0.005


def test_every_flag_says_why_and_the_markdown_lists_the_flags(audited):
    doc = _doc(audited)
    flagged = [e for e in doc["edges"] if e["decision"] == "flagged"]
    assert all(e["reason"].startswith(("validator", "consistency")) for e in flagged)
    page = (audited / "audit.md").read_text()
    assert f"| loops flagged | {doc['flagged_loops']} of {doc['loops_total']} |" in page
    assert "(injected)" in page
    assert "![side-by-side](" in page and (audited / "maps" / "side-by-side.png").exists()


def test_the_cleaned_graph_reads_back_into_gtsam_and_into_audit(audited, graph):
    doc = _doc(audited)
    clean = audited / "clean.g2o"
    factors, values = gtsam.readG2o(str(clean), False)
    assert values.size() == doc["vertices"]
    # The injected loops are gone; every sequential edge stays (flagged ones widened).
    assert factors.nrFactors() == doc["edges_total"] - doc["flagged_loops"]
    again = read_graph(clean)
    assert again.scans is not None and len(again.scans) == doc["vertices"]
    original = read_graph(graph)
    assert original.scans is not None
    for k in (0, len(again) // 2, len(again) - 1):
        assert np.allclose(again.scans[k].points(), original.scans[k].points(), atol=1e-3)


def test_the_flagged_edges_open_as_an_edges_file_whose_scans_are_the_graphs(audited, graph):
    doc = _doc(audited)
    edges = read_edges(audited / "flagged.jsonl")
    assert len(edges) == doc["flagged_total"]
    scans = EdgeScans()
    vertex_scans = open_log(graph).scans
    for e in edges[:3]:
        a, _ = scans.scans(e)
        assert np.allclose(a.points(), vertex_scans[e.a].points())
        assert e.match["audit"]["reason"]
        assert e.match["slam"]["kept"] is False


def test_the_recording_shows_kept_and_flagged_edges_over_the_maps(audited):
    store = RrdReader(audited / "audit.rrd").stream().collect()
    paths = {str(chunk.entity_path) for chunk in store.stream().to_chunks()}
    assert {"/world/maps/input", "/world/maps/before", "/world/maps/after"} <= paths
    assert any(p.startswith("/world/edges/kept") for p in paths)
    assert any(p.startswith("/world/edges/rejected") for p in paths)


def test_scans_from_the_log_tied_by_vertex_times_or_index_judge_alike(
    demo, graph, audited, tmp_path
):
    """The same graph without its scans, tied to the log by a TUM file of vertex times and
    by vertex id = scan index, is judged as it is with its own scans."""
    g = read_graph(graph)
    assert g.scans is not None
    bare = tmp_path / "bare.g2o"
    bare.write_text(
        "".join(line for line in graph.read_text().splitlines(True) if "ROBOTLASER1" not in line)
    )
    times = tmp_path / "vertices.txt"
    write_tum(times, g.timestamps, g.poses)
    log = open_log(demo)
    by_time = tmp_path / "by-time.json"
    cmd.main(
        [
            "audit", str(bare), "--scans", str(demo), "--vertex-times", str(times),
            "--json", str(by_time),
        ]
    )  # fmt: skip
    doc = json.loads(by_time.read_text())
    assert doc["vertices"] == len(g) and doc["edges_total"] == len(g.edges)
    inline = tmp_path / "inline.json"
    cmd.main(["audit", str(graph), "--json", str(inline)])
    decisions = [e["decision"] for e in json.loads(inline.read_text())["edges"]]
    same = sum(a == e["decision"] for a, e in zip(decisions, doc["edges"], strict=True))
    assert same >= 0.95 * len(decisions)
    # Vertex id = scan index: a graph whose ids are the keyframes' scan indices.
    scan_of = np.searchsorted(log.timestamps, g.timestamps)
    assert np.allclose(log.timestamps[scan_of], g.timestamps)
    text = bare.read_text()
    for k in range(len(g) - 1, -1, -1):  # highest first, so no id is renamed twice
        text = text.replace(f"VERTEX_SE2 {k} ", f"VERTEX_SE2 {scan_of[k]} ")
    renamed = tmp_path / "renamed.g2o"
    lines = []
    for line in text.splitlines():
        parts = line.split()
        if parts and parts[0] in ("EDGE_SE2", "FIX"):
            for i in (1, 2) if parts[0] == "EDGE_SE2" else (1,):
                parts[i] = str(scan_of[int(parts[i])])
            line = " ".join(parts)
        lines.append(line)
    renamed.write_text("\n".join(lines) + "\n")
    by_index = tmp_path / "by-index.json"
    cmd.main(
        [
            "audit", str(renamed), "--scans", str(demo), "--vertex-index", "scan",
            "--json", str(by_index),
        ]
    )  # fmt: skip
    indexed = json.loads(by_index.read_text())
    first = indexed["edges"][0]
    assert (first["from"], first["to"]) == (int(scan_of[0]), int(scan_of[1]))
    same = sum(a == e["decision"] for a, e in zip(decisions, indexed["edges"], strict=True))
    assert same >= 0.95 * len(decisions)


def test_a_toro_graph_reads_with_its_information_order(tmp_path):
    path = tmp_path / "small.graph"
    path.write_text(
        "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nVERTEX2 2 2 0 0\n"
        "EDGE2 1 0 -1 0 0 10 1 20 30 2 3\nEDGE2 1 2 1 0 0 10 0 10 100 0 0\n"
    )
    g = read_graph(path)
    assert g.format == "toro" and len(g) == 3 and g.scans is None
    info = g.edges[0].information
    # EDGE2's order is I11 I12 I22 I33 I13 I23.
    assert info[0, 0] == 10 and info[0, 1] == 1 and info[1, 1] == 20
    assert info[2, 2] == 30 and info[0, 2] == 2 and info[1, 2] == 3
    assert (g.edges[0].a, g.edges[0].b) == (1, 0)


def test_g2o_information_is_the_upper_triangle_in_row_order(tmp_path):
    path = tmp_path / "small.g2o"
    path.write_text(
        "VERTEX_SE2 5 0 0 0\nVERTEX_SE2 9 1 0 0.1\nFIX 5\nEDGE_SE2 5 9 1 0 0.1 10 1 2 20 3 30\n"
    )
    g = read_graph(path)
    assert list(g.ids) == [5, 9] and g.fixed == 0
    info = g.edges[0].information
    assert info[0, 1] == 1 and info[0, 2] == 2 and info[1, 1] == 20 and info[1, 2] == 3
    assert info[2, 2] == 30 and np.allclose(info, info.T)


_GOOD = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
_BAD = {
    "unknown line": (_GOOD + "VERTEX_XY 7 1 2\n", 4, "not a line of a 2D pose graph"),
    "vertex no edge names": (
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n"
        "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n",
        3,
        "named by no edge",
    ),
    "edge to a missing vertex": (_GOOD + "EDGE_SE2 1 4 1 0 0 1 0 0 1 0 1\n", 4, "vertex 4"),
    "information not positive definite": (
        _GOOD.replace("1 0 0 1 0 1\n", "1 0 0 -1 0 1\n"),
        3,
        "not positive definite",
    ),
    "NaN": (_GOOD.replace("VERTEX_SE2 1 1 0 0", "VERTEX_SE2 1 nan 0 0"), 2, "NaN"),
    "a vertex twice": (_GOOD + "VERTEX_SE2 1 2 0 0\n", 4, "vertex 1 again"),
    "a field short": (_GOOD + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", 4, "fields"),
}


@pytest.mark.parametrize("case", sorted(_BAD))
def test_a_bad_graph_file_gives_one_line_naming_file_and_line(case, tmp_path, capsys):
    text, line, words = _BAD[case]
    path = tmp_path / "bad.g2o"
    path.write_text(text)
    with pytest.raises(InputError) as raised:
        read_graph(path)
    assert str(raised.value).startswith(f"{path}:{line}: "), str(raised.value)
    assert words in str(raised.value)
    with pytest.raises(SystemExit) as code:
        cmd.main(["audit", str(path)])
    assert code.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{path}:{line}:" in err[0] and "Traceback" not in err[0]


def test_careless_audit_commands_get_one_line(graph, demo, tmp_path, capsys):
    bare = tmp_path / "bare.g2o"
    bare.write_text(_GOOD)
    cases = [
        (["audit", str(tmp_path / "nope.g2o")], "no such file"),
        (["audit", str(bare)], "--scans"),
        (["audit", str(bare), "--scans", str(demo)], "--vertex-times"),
        (["audit", str(graph), "--vertex-index", "scan"], "--scans"),
        (["audit", str(demo)], "this is a log, not a pose graph"),
        (["audit", str(bare), "--scans", str(demo), "--vertex-index", "scan",
          "--vertex-times", str(bare)], "not both"),
    ]  # fmt: skip
    for argv, words in cases:
        with pytest.raises(SystemExit) as code:
            cmd.main(argv)
        assert code.value.code != 0, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], (argv, err)
