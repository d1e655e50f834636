"""``vgm-studio slam`` end to end on a simulated office with injected false loop closures."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import rerun.chunk as rc

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.tools import cmd

FALSE_LOOPS = 10


def run(*args: str | Path) -> None:
    """The command as ``vgm-studio`` runs it, in this process."""
    cmd.main(["slam", *map(str, args)])


def write_relations(log_path: Path, out: Path, seed: int = 0) -> Path:
    """Freiburg relations from the simulator's TRUEPOS: short, medium and random long pairs."""
    log = open_log(log_path)
    ref, t = log.reference_poses(), log.timestamps
    assert ref is not None
    pairs = [(a, a + k) for a in range(0, len(log) - 40, 3) for k in (5, 20, 40)]
    rng = np.random.default_rng(seed)
    pairs += [tuple(sorted(rng.choice(len(log), 2, replace=False))) for _ in range(300)]
    lines = []
    for a, b in pairs:
        d = se2.between(ref[a], ref[b])
        lines.append(f"{t[a]:.6f} {t[b]:.6f} {d[0]:.6f} {d[1]:.6f} 0 0 0 {d[2]:.6f}")
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.fixture(scope="module")
def office(tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("office")
    log = simulate(SimConfig(preset="office", seed=1, num_beams=181, scan_spacing=0.2), folder)
    return log, write_relations(log, folder / "office.relations")


@pytest.fixture(scope="module")
def runs(office, tmp_path_factory) -> dict[str, dict]:
    """One run per validator; vgmnet's also writes maps and a recording."""
    log, relations = office
    out = tmp_path_factory.mktemp("runs")
    results = {}
    for validator in ("none", "vgmnet", "reference"):
        extra: list[str | Path] = []
        if validator == "none":
            # No validation and no consistency check: every candidate goes in.
            extra = ["--consistency", "none"]
        if validator == "vgmnet":
            extra = ["--map-png", out / "maps", "--record", out / "run.rrd"]
            extra += ["--loops-out", out / "loops.jsonl"]
        run(
            log,
            "--validator", validator,
            "--relations", relations,
            "--inject-false-loops", str(FALSE_LOOPS),
            "--json", out / f"{validator}.json",
            *extra,
        )  # fmt: skip
        # Strict JSON: a figure not measured (p with no model, a loop's overlap) is null.
        text = (out / f"{validator}.json").read_text()
        results[validator] = json.loads(text, parse_constant=_not_json)
    results["_out"] = {"path": out}  # type: ignore[assignment]
    return results


def _not_json(name: str) -> None:
    raise AssertionError(f"{name} in the JSON document")


@pytest.mark.long
def test_validation_rejects_injected_loops_and_lowers_the_relation_error(runs):
    none, vgmnet, ref = runs["none"], runs["vgmnet"], runs["reference"]
    for doc in (none, vgmnet, ref):
        assert doc["injected_false_loops"] == FALSE_LOOPS
        assert doc["edges_kept"] + doc["edges_rejected"] == doc["edges_total"]
        assert set(doc["before"]) == {"trans_mean", "trans_std", "rot_mean_deg", "rot_std_deg", "n"}
        assert doc["after"]["n"] > 1000 and doc["seconds"] > 0
    # Without validation or consistency every false loop the matcher could place goes in and
    # bends the graph by metres; only failed matches (no pose scored) stay out.
    assert none["injected_false_loops_kept"] >= FALSE_LOOPS // 2
    assert none["edges_rejected"] == none["loops_total"] - none["loops_validator_kept"]
    assert none["loops_consistency_rejected"] == 0
    assert none["after"] == none["before"] and none["after"]["trans_mean"] > 1.0
    for doc in (vgmnet, ref):
        assert doc["injected_false_loops_kept"] == 0
        assert doc["loops_kept"] >= 20
        assert doc["after"]["trans_mean"] < 0.1 * none["after"]["trans_mean"]
        assert doc["after"]["trans_mean"] < doc["odometry"]["trans_mean"]
        assert doc["after"]["trans_mean"] < doc["before"]["trans_mean"]
    assert ref["after"]["trans_mean"] < 0.05


@pytest.mark.long
def test_loops_out_holds_every_matched_loop_labelled_by_the_reference(office, runs):
    from vgm_studio.matching.edges import read_edges
    from vgm_studio.model.training import read_labelled

    doc, path = runs["vgmnet"], runs["_out"]["path"] / "loops.jsonl"
    edges = read_edges(path)
    log = open_log(office[0])
    ref = log.reference_poses()
    assert ref is not None
    decided = [e.match["slam"] for e in edges]
    # Every loop the run kept is in the file (no injected loop was kept), and the file holds
    # the rejected ones too.
    assert sum(d["kept"] for d in decided) == doc["loops_kept"] >= 20
    assert len(edges) > doc["loops_kept"]
    assert not any(d["source"] == "injected" for d in decided)
    for e, d in zip(edges, decided, strict=True):
        # Log scans, not keyframe indices, and the reference the label was measured on.
        assert 0 <= e.a < e.b < len(log) and d["keyframes"][0] < d["keyframes"][1]
        np.testing.assert_allclose(e.reference, se2.between(ref[e.a], ref[e.b]), atol=1e-9)
        assert e.label in ("success", "failure", "ambiguous") and e.kind == "loop"
        assert e.params["read"]["fov_deg"] == 180.0
    pairs = list(zip(edges, decided, strict=True))
    kept = [e for e, d in pairs if d["kept"]]
    # The run keeps no false loop; a few kept ones are a little looser than a success label
    # (0.1 m), as loops judged by their trail's overlap may be.
    for e in kept:
        xy, theta = se2.pose_error(e.reference, e.estimate)
        assert xy < 0.5 and np.degrees(theta) < 3.0, (e.a, e.b, xy, theta)
    assert sum(e.label == "success" for e in kept) >= 0.8 * len(kept)
    # What the validator rejected holds failures: what a validator learns from.
    assert any(e.label == "failure" and not d["validated"] for e, d in pairs)
    # A file `vgm-studio train` reads: each labelled loop's VGM made from the log's scans.
    data = read_labelled([path], progress=False)
    assert len(data.samples) == sum(e.label in ("success", "failure") for e in edges)


@pytest.mark.long
def test_maps_are_written_and_the_validated_one_is_the_sharper(runs):
    import cv2

    maps = runs["_out"]["path"] / "maps"
    images = {
        n: cv2.imread(str(maps / f"{n}.png"), cv2.IMREAD_GRAYSCALE)
        for n in ("odometry", "before", "after")
    }
    assert all(img is not None and img.size > 100_000 for img in images.values())
    side = cv2.imread(str(maps / "side-by-side.png"), cv2.IMREAD_GRAYSCALE)
    assert side.shape[1] > sum(i.shape[1] for i in images.values())
    # A bent graph scatters the scans: the map it makes sees far more of the plane.
    known = {n: int((img != 128).sum()) for n, img in images.items()}
    assert known["after"] < 0.7 * known["before"]


@pytest.mark.long
def test_recording_reads_back_with_every_entity(runs):
    doc = runs["vgmnet"]
    store = rc.RrdReader(runs["_out"]["path"] / "run.rrd").stream().collect()
    chunks = store.stream().to_chunks()
    paths = Counter(c.entity_path for c in chunks)
    for path in (
        "/world/maps/odometry",
        "/world/maps/before",
        "/world/maps/after",
        "/world/trajectory/after",
        "/world/scan",
        "/world/edges/kept",
        "/world/edges/rejected",
        "/inspector/vgm",
        "/inspector/verdict",
        "/metrics/relation_error/after/trans_mean",
    ):
        assert path in paths, path

    def strips(path: str) -> int:
        count = 0
        for c in chunks:
            if c.entity_path == path:
                batch = c.to_record_batch()
                if "LineStrips2D:strips" in batch.schema.names:
                    count += sum(
                        len(row) for row in batch.column("LineStrips2D:strips").to_pylist()
                    )
        return count

    assert strips("/world/edges/kept") == doc["edges_kept"]
    rejected = strips("/world/edges/rejected")
    inconsistent = strips("/world/edges/inconsistent")
    assert rejected + inconsistent == doc["edges_rejected"]
    assert inconsistent == doc["loops_consistency_rejected"]
    loops = [e for e in doc["edges"] if e["kind"] == "loop"]
    assert len(loops) == doc["loops_total"] and len(doc["edges"]) == doc["edges_total"]
    assert {e["source"] for e in loops} <= {"window", "place", "sweep", "injected"}
    assert doc["loops_by_source"] == {
        s: sum(e["source"] == s for e in loops) for s in ("window", "place", "sweep", "injected")
    }
    assert sum(e["source"] == "injected" for e in loops) == FALSE_LOOPS
    assert all(e["consistency"] == "not-checked" for e in loops if e["validator"] == "rejected")
    assert sum(e["validator"] == "kept" for e in loops) == doc["loops_validator_kept"]
    at_match = [e for e in doc["edges"] if e["at_match"]]
    assert len(at_match) == doc["sequential_at_match"]
    assert all(e["kind"] == "sequential" and not e["kept"] for e in at_match)
    rejected_seq = doc["edges_rejected"] - (doc["loops_total"] - doc["loops_kept"])
    images = sum(c.to_record_batch().num_rows for c in chunks if c.entity_path == "/inspector/vgm")
    assert images == doc["loops_total"] + rejected_seq
    maps = [c for c in chunks if c.entity_path.startswith("/world/maps/")]
    assert any("Image:buffer" in c.to_record_batch().schema.names for c in maps)
    assert all(c.is_static for c in maps)
    assert "keyframe" in next(c for c in chunks if c.entity_path == "/world/scan").timeline_names


@pytest.mark.long
def test_the_final_sweep_can_be_switched_off(office, runs, tmp_path):
    """``--no-final-sweep`` reaches the front end: the run records it and no loop comes
    from the sweep."""
    log, _ = office
    assert runs["vgmnet"]["settings"]["front_end"]["final_sweep"] is True
    out = tmp_path / "run.json"
    cmd.main(["slam", str(log), "--no-final-sweep", "--json", str(out)])
    doc = json.loads(out.read_text())
    assert doc["settings"]["front_end"]["final_sweep"] is False
    assert doc["loops_by_source"]["sweep"] == 0
    assert doc["loops_by_source"]["window"] > 0  # the online search still ran


def test_bad_inputs_end_as_one_line(office, tmp_path, capsys):
    log, _ = office
    bad = tmp_path / "bad.relations"
    bad.write_text("1 2 0 0 0 0 0 0\n1 2 3\n")
    elsewhere = tmp_path / "elsewhere.relations"
    elsewhere.write_text("1000000000 1000000001 0 0 0 0 0 0\n")
    tiny = tmp_path / "tiny.log"
    tiny.write_text("FLASER 3 1 1 1 0 0 0 0 0 0 5 h 5\nFLASER 3 1 1 1 0 0 0 0 0 0 6 h 6\n")
    for args, expected in (
        ((log, "--relations", bad), f"vgm-studio: error: {bad}:2: expected 8 fields"),
        ((log, "--relations", elsewhere), f"vgm-studio: error: {elsewhere}: no relation matches"),
        ((tiny,), f"vgm-studio: error: {tiny}: has 0 scan(s) with at least 10 points"),
        ((log, "--relations", log), f"vgm-studio: error: {log}: is not a Freiburg relations file"),
        ((log, "--validator", "score"), "vgm-studio: error: --validator score needs --model"),
        ((tmp_path / "none.log",), f"vgm-studio: error: {tmp_path / 'none.log'}: no such file"),
        # Said before the run, not after minutes of it.
        ((log, "--loops-out", tmp_path), f"vgm-studio: error: {tmp_path}: is a folder"),
        # The model is checked before the log is read (seconds, on a large log).
        (
            (tmp_path / "none.log", "--model", tmp_path / "none.pt"),
            f"vgm-studio: error: {tmp_path / 'none.pt'}: no such model file",
        ),
    ):
        with pytest.raises(SystemExit) as exit_info:
            run(*args)
        assert exit_info.value.code == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(expected), err
