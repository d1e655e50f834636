"""Shared fixtures: where the real datasets are, and small logs written on the fly."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--full",
        action="store_true",
        help="also run the long end-to-end tests (marked long); .ci/run always does",
    )


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist each worker's torch uses one thread: two workers with two threads
    each on two cores make torch's threads wait on each other (a training test 3× slower).
    The commands tests start in subprocesses keep the machine's own setting."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        torch.set_num_threads(1)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Without ``--full``, the tests marked ``long`` (whole runs on real logs, a trained model,
    a fleet) are skipped, so that ``pytest`` is a loop of a few minutes; each skip says how to
    run it."""
    if config.getoption("--full"):
        return
    skip = pytest.mark.skip(reason="a long end-to-end test: pytest --full runs it (CI does)")
    for item in items:
        if "long" in item.keywords:
            item.add_marker(skip)


def _datasets_dir() -> Path:
    env = os.environ.get("VGM_STUDIO_DATASETS")
    return Path(env) if env else REPO.parent / "shared" / "datasets"


@pytest.fixture(scope="session")
def datasets() -> Path:
    """The shared real datasets; skipped when absent, but required when CI=true."""
    path = _datasets_dir()
    if not (path / "intel" / "intel.gfs.log").is_file():
        reason = f"real datasets not found at {path} (set VGM_STUDIO_DATASETS)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"CI=true but {reason}")
        pytest.skip(reason)
    return path


@pytest.fixture(scope="session")
def artifacts() -> Path:
    """A folder for pictures tests make, kept after the run for people to look at."""
    path = REPO / "test-artifacts"
    path.mkdir(exist_ok=True)
    return path


@pytest.fixture(scope="session")
def office_edges(tmp_path_factory) -> Path:
    """A small simulated office log and its labelled candidate edges (JSONL), made once."""
    from vgm_studio.datasets import open_log
    from vgm_studio.matching.candidates import CandidateConfig, make_candidates
    from vgm_studio.matching.edges import write_edges
    from vgm_studio.matching.matcher import ScanMatcher
    from vgm_studio.simulation.simulate import SimConfig, simulate

    folder = tmp_path_factory.mktemp("office")
    log = open_log(simulate(SimConfig(preset="office", seed=5, laps=1.0, num_beams=181), folder))
    edges = make_candidates(
        log,
        ScanMatcher(),
        CandidateConfig(max_loops=40, seed=5, keyframe_distance=1.0),
        progress=False,
    )
    path = folder / "edges.jsonl"
    write_edges(path, edges)
    return path


@pytest.fixture(scope="session")
def pg_server():
    """A real PostgreSQL server from Debian's binaries on a free loopback port, for the session.

    Yields a callable ``(name) -> URL`` that makes a fresh database (``.restart()`` restarts the
    server); the server is stopped and its folder removed at the end. Skipped without the
    binaries, but required when CI=true.
    """
    from benchmarks.pg_local import LocalPostgres, pg_bin

    bindir = pg_bin()
    if bindir is None:
        reason = "PostgreSQL binaries not found (/usr/lib/postgresql/*/bin; apt install postgresql)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"CI=true but {reason}")
        pytest.skip(reason)
    server = LocalPostgres(bindir)
    server.start()

    def new_database(name: str = "t") -> str:
        return server.new_database(name)

    new_database.restart = server.restart  # type: ignore[attr-defined]
    try:
        yield new_database
    finally:
        server.stop()


@pytest.fixture(scope="session")
def balanced_office_edges(office_edges) -> Path:
    """The office edges' successes, each sequential one also moved by 0.6 m / 9° as a failure
    (at most 80): the office log's matches nearly all succeed, and a trainer needs both
    classes to learn from. Written beside the office edges; the scans are the same log's."""
    from dataclasses import replace

    from vgm_studio.matching.edges import edge_id, read_edges, write_edges

    out = []
    for e in read_edges(office_edges):
        if e.label != "success":
            continue
        out.append(e)
        if e.kind == "sequential" and len(out) < 160:
            est = [e.estimate[0] + 0.6, e.estimate[1] - 0.4, e.estimate[2] + 0.15]
            moved = edge_id(e.log_sha256, e.a, e.b, est)
            out.append(replace(e, edge_id=moved, estimate=est, label="failure"))
    path = office_edges.parent / "balanced.jsonl"
    write_edges(path, out)
    return path


@pytest.fixture(scope="session")
def needs_chromium() -> None:
    """Skips a browser test without Debian's chromium; under CI=true its absence fails."""
    from benchmarks.studio_browser import chromium_path

    if chromium_path() is None:
        reason = "Debian chromium is not installed (.ci/run installs it)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"CI=true but {reason}")
        pytest.skip(reason)
