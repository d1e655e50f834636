"""The repository's own files: the licence pyproject names, and a .gitignore that keeps what
README's examples write out of ``git status``."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

REPO = Path(__file__).resolve().parents[1]

# Options whose value is a file or folder the command writes.
WRITES = (
    "--out",
    "--map-png",
    "--record",
    "--json",
    "--png",
    "--workspace",
    "--markdown",
    "--g2o",
    "--trajectory",
    "--ros-map",
    "--edges-out",
    "--loops-out",
)


def _bash_blocks(text: str) -> str:
    return "\n".join(re.findall(r"```bash\n(.*?)```", text, flags=re.DOTALL))


def _written_paths() -> set[str]:
    """What README's shell examples write, relative to the folder they run in."""
    found = set()
    for option, value in re.findall(
        r"(--[a-z-]+)[ =]([^\s-]\S*)", _bash_blocks(REPO.joinpath("README.md").read_text())
    ):
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
def test_what_readmes_examples_write_is_ignored():
    written = _written_paths()
    # The examples this test exists for: maps and a fleet's folder, and the state a
    # stopped training run keeps beside its checkpoint.
    assert {"maps", "fleet-out", "intel.jsonl", "intel.studio"} <= written
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
