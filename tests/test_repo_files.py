"""The repository's own files: the licence pyproject names, and a .gitignore that keeps what
the examples of README and the docs pages write out of ``git status``."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.doc_examples import WRITES, bash_text, doc_pages

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

REPO = Path(__file__).resolve().parents[1]


def _written_paths() -> set[str]:
    """What the shell examples of README and the docs pages write, relative to the folder
    they run in."""
    found = set()
    for page in doc_pages():
        for option, value in re.findall(r"(--[a-z0-9-]+)[ =]([^\s-]\S*)", bash_text(page)):
            if option not in WRITES or value.startswith(("..", "/", "$", "<")):
                continue
            if value.split("/")[0] in ("datasets", "assets"):  # the bundled files, tracked
                continue
            found.add(value)
    return found


def test_the_licence_file_is_the_one_pyproject_names():
    declared = tomllib.loads(REPO.joinpath("pyproject.toml").read_text())["project"]["license"]
    assert declared == {"text": "MIT"}
    text = REPO.joinpath("LICENSE").read_text()
    assert text.startswith("MIT License")
    assert "Copyright (c) 2026 VGM Studio contributors" in text
    assert 'THE SOFTWARE IS PROVIDED "AS IS"' in text


@pytest.mark.skipif(
    shutil.which("git") is None or not REPO.joinpath(".git").exists(), reason="not a git checkout"
)
def test_what_the_docs_examples_write_is_ignored():
    """Every file or folder an example of README or of the docs pages writes where it runs
    (the repository root) is ignored by git, and so is what an interrupted training run
    leaves beside its checkpoint."""
    written = _written_paths()
    # The examples this test exists for: maps, a fleet's folder, a studio's workspace and an
    # export's JSONL; and, below, what an interrupted training run leaves beside its checkpoint.
    assert {"maps", "fleet-out", "intel.studio", "labels.jsonl"} <= written
    extra = ["mine.pt.partial", "models/sub/fhw-model.pt.partial", "labels.models/v1.pt"]
    paths = [*sorted(written), *(f"{p}/x" for p in sorted(written)), *extra]
    proc = subprocess.run(
        ["git", "check-ignore", "--no-index", "--verbose", "--non-matching", *paths],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=False,
    )
    unmatched = {line.split("\t")[-1] for line in proc.stdout.splitlines() if line.startswith("::")}
    # A path counts as ignored as a file or as a folder (``/maps/`` matches only a folder,
    # and git cannot tell which a path that is not there would be).
    missing = [p for p in sorted(written) if {p, f"{p}/x"} <= unmatched]
    assert missing + [p for p in extra if p in unmatched] == []
