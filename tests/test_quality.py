"""Lint, format and type checks run as part of the tests."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _check(*args: str) -> None:
    proc = subprocess.run([sys.executable, "-m", *args], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 0, f"{' '.join(args)} failed:\n{proc.stdout}\n{proc.stderr}"


def test_ruff_lint():
    _check("ruff", "check", ".")


def test_ruff_format():
    _check("ruff", "format", "--check", ".")


def test_mypy():
    _check("mypy")
