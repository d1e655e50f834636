"""The SLAM run's stages on a short simulated log, and its recording read back with rerun's
reader: keyframes and edges, both decisions per loop, reference scoring, a robot that never
moved."""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import rerun.chunk as rc

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.recording import write_recording
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam.config import FrontEndConfig, SlamConfig, ValidationConfig
from vgm_studio.slam.pipeline import dense_reference, run_slam, scan_poses
from vgm_studio.slam.report import errors_of, run_maps
from vgm_studio.slam.scoring import relations_from_reference
from vgm_studio.tools import cmd

INJECTED = 4


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("demo")
    return simulate(SimConfig(preset="demo", seed=2, num_beams=181), folder)


@pytest.fixture(scope="module")
def run(demo):
    log = open_log(demo)
    config = SlamConfig(
        front_end=FrontEndConfig(false_loops=INJECTED, seed=2),
        validation=ValidationConfig(validator="reference"),
    )
    return log, run_slam(log, config, progress=False)


def test_keyframes_sequential_edges_and_loops_with_their_sources_and_decisions(run):
    log, result = run
    k = len(result.keyframes)
    assert k > 50 and np.all(np.diff(result.keyframes) > 0)
    sequential = [e for e in result.edges if e.kind == "sequential"]
    assert [(e.a, e.b) for e in sequential] == [(i - 1, i) for i in range(1, k)]
    assert all(e.source == "odometry" and e.consistency == "not-checked" for e in sequential)
    loops = [e for e in result.edges if e.kind == "loop"]
    sources = Counter(e.source for e in loops)
    assert sources["injected"] == INJECTED and sources["window"] > 10
    assert all(e.injected == (e.source == "injected") for e in loops)
    # The consistency check decides on exactly the loops the validator passed.
    assert all((e.consistency != "not-checked") == e.validated for e in loops)
    assert all(e.kept == (e.validated and e.consistency == "kept") for e in loops)
    assert not any(e.kept for e in loops if e.injected)
    reference = dense_reference(log, result.odometry)
    assert reference is not None
    ref = reference[result.keyframes]
    for e in loops:
        if e.kept:
            err = se2.between(se2.between(ref[e.a], ref[e.b]), e.estimate)
            assert math.hypot(err[0], err[1]) < 0.3 and abs(err[2]) < math.radians(3)


def test_relations_from_the_simulators_reference_show_the_loops_help(run):
    log, result = run
    relations = relations_from_reference(log)
    assert relations is not None and len(relations) > 100
    errors = errors_of(result, relations)
    assert errors is not None and set(errors) == {"odometry", "before", "after"}
    assert errors_of(result, None) is None
    assert errors["after"].trans_mean < errors["odometry"].trans_mean
    assert errors["after"].trans_mean < 0.05


def _chunks(path: Path, kind: str = "recording") -> list:
    reader = rc.RrdReader(path)
    stores = reader.recordings() if kind == "recording" else reader.blueprints()
    assert len(stores) == 1
    return list(reader.stream(store=stores[0]).to_chunks())


def _strips(chunks: list, path: str) -> int:
    count = 0
    for c in chunks:
        batch = c.to_record_batch()
        if c.entity_path == path and "LineStrips2D:strips" in batch.schema.names:
            count += sum(len(row) for row in batch.column("LineStrips2D:strips").to_pylist())
    return count


def test_recording_holds_every_edge_decision_and_the_blueprint(run, tmp_path):
    log, result = run
    path = tmp_path / "run.rrd"
    write_recording(log, result, run_maps(log, result, SlamConfig().maps), None, path)
    chunks = _chunks(path)
    assert _strips(chunks, "/world/edges/kept") == sum(e.kept for e in result.edges)
    assert _strips(chunks, "/world/edges/rejected") == sum(not e.validated for e in result.edges)
    assert _strips(chunks, "/world/edges/inconsistent") == sum(
        e.consistency == "rejected" for e in result.edges
    )
    verdicts = [
        text
        for c in chunks
        if c.entity_path == "/inspector/verdict"
        for text in c.to_record_batch().column("TextDocument:text").to_pylist()
    ]
    flat = [t[0] if isinstance(t, list) else t for t in verdicts]
    assert len(flat) == sum(e.kind == "loop" or not e.kept for e in result.edges)
    assert all("source " in t and "consistency " in t and "validator " in t for t in flat)
    assert sum("source injected" in t for t in flat) == INJECTED
    names = []
    for c in _chunks(path, "blueprint"):
        batch = c.to_record_batch()
        if "ViewBlueprint:display_name" in batch.schema.names:
            names += [n[0] for n in batch.column("ViewBlueprint:display_name").to_pylist()]
    assert sorted(names) == sorted(
        ["map", "edge inspector (VGM)", "verdict", "metrics", "p(success)"]
    )


def test_a_robot_that_never_moved_makes_a_readable_recording(tmp_path):
    ranges = " ".join(f"{2 + math.sin(i / 10):.3f}" for i in range(181))
    lines = []
    for k in range(30):
        t = 1000 + 0.1 * k
        lines += [f"ODOM 0 0 0 0 0 0 {t:.3f} h {t:.3f}"]
        lines += [f"FLASER 181 {ranges} 0 0 0 0 0 0 {t:.3f} h {t:.3f}"]
    log = tmp_path / "still.log"
    log.write_text("\n".join(lines) + "\n")
    rrd, out = tmp_path / "still.rrd", tmp_path / "still.json"
    cmd.main(["slam", str(log), "--validator", "none", "--record", str(rrd), "--json", str(out)])
    doc = json.loads(out.read_text())
    assert doc["keyframes"] == 1 and doc["edges_total"] == 0 and doc["edges"] == []
    paths = {c.entity_path for c in _chunks(rrd)}
    assert {"/world/scan", "/world/trajectory/after", "/metrics/edges/loops_kept"} <= paths
    assert not any(p.startswith("/world/edges/") for p in paths)


def test_a_simulated_log_scores_against_its_own_reference_without_a_relations_file(
    demo, tmp_path, capsys
):
    out = tmp_path / "demo.json"
    cmd.main(["slam", str(demo), "--validator", "reference", "--json", str(out)])
    doc = json.loads(out.read_text())
    said = capsys.readouterr()
    assert "relations drawn from the reference poses" in said.out
    assert "no loop" not in said.out + said.err
    for name in ("odometry", "before", "after"):
        assert set(doc[name]) == {"trans_mean", "trans_std", "rot_mean_deg", "rot_std_deg", "n"}
        assert doc[name]["n"] > 100
    assert doc["after"]["trans_mean"] < doc["odometry"]["trans_mean"]


@pytest.mark.long
def test_a_corrected_log_scores_against_its_corrected_poses_however_it_is_read(datasets, tmp_path):
    log = datasets / "radish-corrected" / "belgioioso-corrected.log"
    docs = {}
    for tag, extra in (
        ("auto", []),
        ("same-reference", ["--reference", str(log)]),
        ("poses-odometry", ["--poses", "odometry"]),
    ):
        out = tmp_path / f"{tag}.json"
        cmd.main(["slam", str(log), "--validator", "none", "--json", str(out), *extra])
        docs[tag] = json.loads(out.read_text())
    # Same relations however the log is named or read: drawn from the same corrected poses.
    assert docs["auto"]["after"]["n"] == docs["same-reference"]["after"]["n"] > 100
    assert docs["poses-odometry"]["after"]["n"] == docs["auto"]["after"]["n"]
    assert docs["auto"]["after"] == docs["same-reference"]["after"]
    # Read as odometry, the corrected poses drive the run, so its odometry is near exact.
    assert docs["poses-odometry"]["odometry"]["trans_mean"] < docs["auto"]["odometry"]["trans_mean"]


@pytest.mark.long
def test_odometry_on_a_few_scans_is_not_used_and_not_warned_of(datasets, tmp_path, capsys):
    """Örebro's log holds raw odometry for 34 of its 237 scans: the run goes without it, says
    so, and does not warn that the scans disagree with odometry it never used (it once
    blamed the laser's mount)."""
    log = datasets / "radish-corrected" / "orebro-corrected.log"
    out = tmp_path / "orebro.json"
    cmd.main(["slam", str(log), "--json", str(out)])
    said = capsys.readouterr()
    assert "odometry on 34 of 237 scans only" in said.out + said.err
    assert "disagree" not in said.out + said.err
    doc = json.loads(out.read_text())
    assert doc["after"]["trans_mean"] < doc["odometry"]["trans_mean"]


def test_scans_between_keyframes_share_both_keyframes_corrections():
    # Odometry that drifts sideways 1 cm per scan over a straight 2 m run; the keyframes
    # (every tenth scan) are put back on the true line.
    steps = np.arange(21, dtype=np.float64)
    truth = np.column_stack([0.1 * steps, np.zeros(21), np.zeros(21)])
    odometry = truth + np.column_stack([np.zeros(21), 0.01 * steps, np.zeros(21)])
    keyframes = np.array([0, 10, 20])
    poses = scan_poses(truth[keyframes], keyframes, odometry)
    # Keyframes stay where the graph put them; scans between lie on the line, not carrying
    # the drift since their keyframe (up to 9 cm with the odometry alone).
    np.testing.assert_allclose(poses[keyframes], truth[keyframes], atol=1e-12)
    np.testing.assert_allclose(poses, truth, atol=1e-9)
    # Past the last keyframe its correction alone; before the first, the first's.
    longer = np.vstack([odometry, [[2.1, 0.21, 0.0]]])
    tail = scan_poses(truth[keyframes], keyframes, longer)[-1]
    np.testing.assert_allclose(tail, [2.1, 0.01, 0.0], atol=1e-9)


def test_a_run_that_closes_no_loop_says_so_and_where_the_loops_went(tmp_path, capsys):
    """Part of a lap: the robot never comes back, the after map is the sequential matches
    alone, and the run says so instead of looking finished."""
    log = simulate(SimConfig(preset="office", seed=3, laps=0.3), tmp_path)
    cmd.main(["slam", str(log), "--validator", "reference"])
    said = capsys.readouterr()
    assert "0 kept after the consistency check" in said.out
    warning = [line for line in said.err.splitlines() if "no loop" in line]
    assert len(warning) == 1
    assert warning[0].startswith(f"{log}: no loop")
    assert "nothing corrects their drift" in warning[0]


def test_a_run_too_short_to_propose_a_loop_says_so(tmp_path, capsys):
    """Fewer keyframes than the loop search's minimum gap: no loop is even proposed."""
    log = simulate(SimConfig(preset="office", seed=3, laps=0.05), tmp_path)
    cmd.main(["slam", str(log), "--validator", "reference"])
    said = capsys.readouterr()
    assert "loops: 0 proposed" in said.out
    assert f"{log}: no loop proposed over" in said.err


def test_every_loop_source_has_a_colour_on_the_edges_map_and_in_the_recording():
    """A source with no colour fails where the edges map orders its loops (a final sweep
    once stopped the infinite corridor's run so)."""
    from typing import get_args

    from vgm_studio.recording.record import COLOURS
    from vgm_studio.slam.edges import EdgeSource
    from vgm_studio.slam.report import LOOP_COLOURS

    sources = set(get_args(EdgeSource)) - {"odometry", "injected"}
    assert {"window", "place", "sweep"} <= sources
    for source in sources:
        assert f"kept ({source})" in LOOP_COLOURS and source in COLOURS, source
    assert len(set(LOOP_COLOURS.values())) == len(LOOP_COLOURS)
