"""Shared fixtures: where the real datasets are, and small logs written on the fly."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


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
