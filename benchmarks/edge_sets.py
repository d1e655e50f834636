"""The model benchmark's edge sets, made with the project's own commands and cached in build/.

Training: the ten GMapping-corrected buildings (their own poses as reference) and simulated
worlds (181 and 361 beams, one moving person). Test: Intel loop candidates from
``intel.gfs.log`` with its own reference poses, the foundation issue's default protocol;
Intel is never trained on.

Run alone to (re)build the sets: python benchmarks/edge_sets.py
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from _common import REPO, datasets_dir

BUILD = REPO / "build" / "edges"
SIM_PRESETS = ("office", "repetitive", "loop", "t-junction", "l-junction", "corridor")
SIM_BEAMS = (181, 361)


def _run(*args: str | Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "vgm_studio.tools.cmd", *map(str, args)],
        check=True,
        stdout=subprocess.DEVNULL,
    )


def training_edges() -> list[Path]:
    """Edge files to train on, made on first use."""
    out = BUILD / "train"
    files = []
    for log in sorted((datasets_dir() / "radish-corrected").glob("*.log")):
        path = out / f"{log.stem}.jsonl"
        if not path.exists():
            _run("candidates", log, "--out", path)
        files.append(path)
    for preset in SIM_PRESETS:
        for beams in SIM_BEAMS:
            path = out / f"sim-{preset}-{beams}.jsonl"
            if not path.exists():
                log = BUILD / "sims" / f"{preset}-seed{beams}.log"
                if not log.exists():
                    _run(
                        "simulate",
                        "--out",
                        log.parent,
                        "--seed",
                        beams,
                        "--preset",
                        preset,
                        "--beams",
                        beams,
                        "--people",
                        1,
                    )
                _run("candidates", log, "--keyframe-distance", 0.5, "--out", path)
            files.append(path)
    return files


def test_edges() -> Path:
    """Intel loop candidates, default protocol (2000 loops, seed 0)."""
    path = BUILD / "test" / "intel-loops.jsonl"
    if not path.exists():
        _run(
            "candidates",
            datasets_dir() / "intel" / "intel.gfs.log",
            "--no-sequential",
            "--out",
            path,
        )
    return path


if __name__ == "__main__":
    for p in [*training_edges(), test_edges()]:
        print(p.relative_to(REPO))
