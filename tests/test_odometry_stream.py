"""The odometry made in a worker while the front end runs: the run it makes is the run that
waited for the whole odometry, edge for edge and pose for pose, even when the worker dies."""

from __future__ import annotations

import gc
import multiprocessing
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.datasets import open_log
from vgm_studio.errors import InputError
from vgm_studio.model.registry import BUNDLED_MODEL
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam import odometry_stream, pipeline
from vgm_studio.slam.config import SlamConfig, ValidationConfig
from vgm_studio.slam.pipeline import run_slam


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("world")
    return open_log(simulate(SimConfig(preset="demo", seed=4, num_beams=181), Path(folder)))


# The bundled model reads local maps: the worker places their neighbours too.
CONFIG = SlamConfig(validation=ValidationConfig(model=BUNDLED_MODEL))


@pytest.fixture(scope="module")
def waited(log):
    """The run that made its whole odometry first (the demo log is too short to stream)."""
    assert len(log) < pipeline.STREAM_FROM
    return run_slam(log, CONFIG, progress=False)


def _streamed(log, monkeypatch, config=None):
    monkeypatch.setattr(pipeline, "STREAM_FROM", 0)
    started = []
    real = odometry_stream.OdometryStream.__init__

    def spied(self, *args, **kwargs):
        started.append(1)
        real(self, *args, **kwargs)

    monkeypatch.setattr(odometry_stream.OdometryStream, "__init__", spied)
    result = run_slam(log, config or CONFIG, progress=False)
    assert started == [1], "the odometry was not streamed"
    return result


def _assert_same_run(got, want):
    np.testing.assert_array_equal(got.odometry, want.odometry)
    np.testing.assert_array_equal(got.keyframes, want.keyframes)
    assert [(e.kind, e.a, e.b, e.kept, e.p_success) for e in got.edges] == [
        (e.kind, e.a, e.b, e.kept, e.p_success) for e in want.edges
    ]
    np.testing.assert_array_equal([e.estimate for e in got.edges], [e.estimate for e in want.edges])
    np.testing.assert_array_equal(got.after.poses, want.after.poses)


def test_a_streamed_run_is_the_run_that_waited_for_its_odometry(log, waited, monkeypatch):
    got = _streamed(log, monkeypatch)
    _assert_same_run(got, waited)
    # The model read local maps, so the worker placed neighbours: the run still kept loops.
    assert sum(e.kind == "loop" and e.kept for e in got.edges) > 10
    assert got.seconds["odometry"] > 0


def test_a_run_whose_odometry_worker_dies_makes_the_odometry_itself(log, waited, monkeypatch):
    real = odometry_stream.OdometryStream.chunks

    def killed(self):
        # Killed while it starts: it has sent nothing (its imports alone take a second).
        os.kill(self._proc.pid, signal.SIGKILL)
        yield from real(self)

    made_here = []
    odometry = pipeline.scan_odometry

    def counted(*args, **kwargs):
        made_here.append(1)
        return odometry(*args, **kwargs)

    monkeypatch.setattr(odometry_stream.OdometryStream, "chunks", killed)
    monkeypatch.setattr(pipeline, "scan_odometry", counted)
    _assert_same_run(_streamed(log, monkeypatch), waited)
    assert made_here == [1]


def test_a_bad_model_ends_a_streamed_run_at_once_and_its_worker_with_it(log, monkeypatch, tmp_path):
    config = SlamConfig(validation=ValidationConfig(model=tmp_path / "missing.pt"))
    monkeypatch.setattr(pipeline, "STREAM_FROM", 0)
    start = time.monotonic()
    with pytest.raises(InputError, match=r"missing\.pt"):
        run_slam(log, config, progress=False)
    gc.collect()
    assert time.monotonic() - start < 10.0
    deadline = time.monotonic() + 10.0
    while multiprocessing.active_children() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not multiprocessing.active_children()


def test_a_keyframe_is_ready_once_every_scan_its_local_map_may_walk_to_is_known():
    from vgm_studio.model.context import Context

    context = Context(neighbours=2, scans=400)
    assert not odometry_stream.ready(100, 500, 10_000, context)
    assert odometry_stream.ready(100, 501, 10_000, context)
    # Near the log's end, the last scan is as far as any walk goes.
    assert odometry_stream.ready(9_900, 10_000, 10_000, context)
    # A model of single scans needs the keyframe's own pose alone.
    assert odometry_stream.ready(100, 101, 10_000, None)
    assert not odometry_stream.ready(100, 100, 10_000, Context(neighbours=0))


def test_the_odometry_worker_goes_with_a_parent_killed_outright(tmp_path):
    from orphans import assert_worker_goes_with_its_parent, stream_parent

    log = simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=0.3), tmp_path)
    parent = stream_parent("vgm_studio.slam.odometry_stream", "OdometryStream")
    assert_worker_goes_with_its_parent(parent, log)


_CTRL_C = """
import sys, time
import numpy as np
from vgm_studio.datasets import open_log
from vgm_studio.slam.between_stream import BetweenStream
from vgm_studio.slam.odometry_stream import OdometryStream

log = open_log(sys.argv[1])
usable = np.ones(len(log), dtype=bool)
step = (0.5, 20.0)
workers = [OdometryStream(log.scans, usable, step), BetweenStream(log.scans, usable, step)]
time.sleep(5)  # both started, and waiting on their queues
try:
    # "ready" inside the try: the test may press Ctrl-C the moment it reads the line.
    print("ready", flush=True)
    time.sleep(60)
except KeyboardInterrupt:
    print("interrupted", file=sys.stderr)
    sys.exit(130)
"""


def test_ctrl_c_stops_a_run_with_one_line_not_a_traceback_from_each_worker(tmp_path):
    import subprocess
    import sys

    log = simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=0.3), tmp_path)
    run = subprocess.Popen(
        [sys.executable, "-c", _CTRL_C, str(log)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    assert run.stdout is not None
    assert run.stdout.readline().strip() == "ready"
    os.killpg(run.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole group
    _, err = run.communicate(timeout=60)
    assert run.returncode == 130
    assert "Traceback" not in err, err
    assert err.strip() == "interrupted"
