"""``vgm-studio fleet`` on a real local Ray with two CPUs, over short simulated logs.

The first run goes through the command line, which starts its own local Ray; the rerun and
the fault test share one Ray started here. A broken log must come back as a failed row while
the others succeed, a rerun must skip the finished logs, each log's figures must be those of
the single-log commands, and a worker killed in the middle of a log must not lose the log.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")
pytest.importorskip("pyarrow")

import ray

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.matching.candidates import CandidateConfig
from vgm_studio.matching.edges import read_edges
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.services.fleet import RayOptions, run_fleet
from vgm_studio.services.fleet_log import FleetSettings
from vgm_studio.services.fleet_table import read_table
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam.config import SlamConfig, ValidationConfig
from vgm_studio.tools import cmd

MAX_LOOPS = 150
# The command line's settings for --max 150 (everything else its defaults).
SETTINGS = FleetSettings(
    slam=SlamConfig(validation=ValidationConfig(model=BUNDLED_MODEL)),
    candidates=CandidateConfig(keyframe_distance=0.5, max_loops=MAX_LOOPS),
)
# Figures of a run that depend on the machine's speed, not on the run.
TIMING = {"seconds", "stage_seconds", "settings"}

# Each test starts Ray and runs several logs: minutes, so they wait for --full.
pytestmark = pytest.mark.long


def _relations(log_path: Path, out: Path) -> Path:
    """Freiburg relations from the simulator's TRUEPOS: pairs 5 and 30 scans apart."""
    log = open_log(log_path)
    ref, t = log.reference_poses(), log.timestamps
    assert ref is not None
    lines = []
    for a in range(0, len(log) - 30, 2):
        for b in (a + 5, a + 30):
            d = se2.between(ref[a], ref[b])
            lines.append(f"{t[a]:.6f} {t[b]:.6f} {d[0]:.6f} {d[1]:.6f} 0 0 0 {d[2]:.6f}")
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    """Two short simulated logs (one with relations) and a broken one, in a manifest."""
    folder = tmp_path_factory.mktemp("fleet-logs")
    loop = simulate(
        SimConfig(preset="loop", seed=1, num_beams=181, scan_spacing=0.3, laps=1.2), folder
    )
    corridor = simulate(
        SimConfig(preset="corridor", seed=2, num_beams=181, scan_spacing=0.3), folder
    )
    relations = _relations(loop, folder / "loop.relations")
    (folder / "broken.clf").write_text("FLASER 3 1.0 oops\n")
    good = [
        {"log": loop.name, "relations": relations.name, "name": "loop"},
        {"log": corridor.name, "name": "corridor"},
    ]
    manifest = folder / "fleet.jsonl"
    manifest.write_text("".join(json.dumps(d) + "\n" for d in [*good, {"log": "broken.clf"}]))
    good_manifest = folder / "good.jsonl"
    good_manifest.write_text("".join(json.dumps(d) + "\n" for d in good))
    return {
        "loop": loop,
        "corridor": corridor,
        "relations": relations,
        "manifest": manifest,
        "good": good_manifest,
    }


@pytest.fixture(scope="module")
def first_run(logs, tmp_path_factory) -> Path:
    """``vgm-studio fleet`` with its own local two-CPU Ray; exits 3 for the broken log."""
    out = tmp_path_factory.mktemp("fleet-out")
    ray_dir = tmp_path_factory.mktemp("r")
    with pytest.raises(SystemExit) as exit_info:
        cmd.main(
            ["fleet", str(logs["manifest"]), "--out", str(out), "--num-cpus", "2",
             "--ray-temp-dir", str(ray_dir), "--max", str(MAX_LOOPS)]
        )  # fmt: skip
    assert exit_info.value.code == 3
    assert not ray.is_initialized()  # the command shut its own Ray down
    return out


@pytest.fixture(scope="module")
def local_ray(first_run, tmp_path_factory):
    """A local Ray with two CPUs for the tests that call the service; shut down at the end."""
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        _temp_dir=str(tmp_path_factory.mktemp("r")),
    )
    yield
    ray.shutdown()


def test_a_broken_log_is_a_failed_row_and_the_others_succeed(first_run, logs):
    rows = read_table(first_run / "fleet.parquet")
    assert [r["name"] for r in rows] == ["loop", "corridor", "broken.clf"]
    loop, corridor, broken = rows
    assert broken["status"] == "failed" and "broken.clf:1:" in broken["error"]
    for row in (loop, corridor):
        assert row["status"] == "done" and row["error"] is None
        assert row["candidates"] > 0 and row["scans"] > 50
        assert row["predicted_success"] + row["predicted_failure"] == row["candidates"]
        assert row["labelled_success"] > 0  # the simulator's TRUEPOS labels them
        assert 0 <= row["loops_kept"] <= row["loops_total"]
        assert Path(row["after_png"]).is_file() and Path(row["edges_file"]).is_file()
        # The worker loaded the model once, in its constructor, not once per log.
        assert row["model_loads"] == 1 and row["attempts"] == 1
    assert loop["loops_total"] > 0
    # The log with a relations file is scored by it; the corridor, which has none, by
    # relations drawn from its own TRUEPOS reference poses (as `slam` scores any such log).
    assert loop["after_trans_mean_m"] is not None and loop["relations_n"] > 100
    assert corridor["after_trans_mean_m"] is not None and corridor["relations_n"] > 0
    assert (first_run / "after-maps.png").stat().st_size > 1000


def _approx(a: object, b: object) -> bool:
    """Equal JSON values, floats within a relative 1e-6."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_approx(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_approx(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float):
        return bool(a == pytest.approx(b, rel=1e-6))
    return a == b


def test_figures_equal_the_single_log_commands(first_run, logs, tmp_path):
    fleet_doc = json.loads((first_run / "logs" / "loop" / "slam.json").read_text())
    single = tmp_path / "slam.json"
    cmd.main(["slam", str(logs["loop"]), "--relations", str(logs["relations"]),
              "--json", str(single)])  # fmt: skip
    single_doc = json.loads(single.read_text())
    assert set(fleet_doc) == set(single_doc)
    for key in set(single_doc) - TIMING:
        # Floats to 1e-6: a batch of other pairs beside an edge moves p(success) by ~1e-7.
        assert _approx(fleet_doc[key], single_doc[key]), key
    row = next(r for r in read_table(first_run / "fleet.parquet") if r["name"] == "loop")
    assert row["loops_kept"] == single_doc["loops_kept"]
    assert row["after_trans_mean_m"] == pytest.approx(single_doc["after"]["trans_mean"])

    edges = tmp_path / "edges.jsonl"
    cmd.main(["candidates", str(logs["loop"]), "--out", str(edges),
              "--reference", str(logs["relations"]),
              "--keyframe-distance", "0.5", "--max", str(MAX_LOOPS)])  # fmt: skip
    single_edges, fleet_edges = read_edges(edges), read_edges(row["edges_file"])
    assert [e.edge_id for e in fleet_edges] == [e.edge_id for e in single_edges]
    labels = Counter(e.label for e in single_edges)
    assert (row["labelled_success"], row["labelled_failure"]) == (
        labels["success"],
        labels["failure"],
    )


def test_a_rerun_skips_the_done_logs(first_run, logs, local_ray):
    before = {n: (first_run / "logs" / n / "row.json").stat().st_mtime_ns
              for n in ("loop", "corridor")}  # fmt: skip
    broken_before = json.loads((first_run / "logs" / "broken.clf" / "row.json").read_text())
    run = run_fleet(logs["manifest"], first_run, SETTINGS, progress=False)
    rows = {r["name"]: r for r in run.rows}
    assert rows["loop"]["skipped"] and rows["corridor"]["skipped"]
    assert not rows["broken.clf"]["skipped"] and rows["broken.clf"]["status"] == "failed"
    for name, mtime in before.items():
        assert (first_run / "logs" / name / "row.json").stat().st_mtime_ns == mtime
    # The broken log alone was run again, by a worker of this run.
    assert rows["broken.clf"]["worker_pid"] != broken_before["worker_pid"]
    assert [r["name"] for r in read_table(first_run / "fleet.parquet")] == list(rows)


def test_a_killed_worker_loses_no_log(logs, local_ray, tmp_path):
    """SIGKILL the worker process of a running log: it is run again, and every log once."""
    out = tmp_path / "out"
    killed: list[str] = []

    def kill_first_running() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            for running in out.glob("logs/*/running.json"):
                try:
                    doc = json.loads(running.read_text())
                except (OSError, ValueError):
                    continue
                time.sleep(0.5)  # well inside the log's work
                os.kill(doc["pid"], signal.SIGKILL)
                killed.append(running.parent.name)
                return
            time.sleep(0.02)

    killer = threading.Thread(target=kill_first_running, daemon=True)
    killer.start()
    run = run_fleet(logs["good"], out, SETTINGS, RayOptions(max_attempts=3), progress=False)
    killer.join()
    assert killed, "no running log was seen to kill"
    rows = read_table(out / "fleet.parquet")
    assert sorted(r["name"] for r in rows) == ["corridor", "loop"]
    assert all(r["status"] == "done" for r in rows), [r["error"] for r in rows]
    by_name = {r["name"]: r for r in rows}
    assert by_name[killed[0]]["attempts"] == 2
    assert np.isfinite(by_name[killed[0]]["seconds"])
    assert not list(out.glob("logs/*/running.json"))
    assert run.workers == 2
