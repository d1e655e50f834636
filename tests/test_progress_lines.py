"""Progress without a terminal: plain lines on stderr, at most every few seconds, and one at
the end; a bar on a terminal; one function for every loop of the package."""

from __future__ import annotations

import ast
import io
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from vgm_studio.progress import EVERY_VARIABLE, Progress, counter, track

PACKAGE = Path(__file__).resolve().parents[1] / "vgm_studio"


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_plain_lines_come_every_ten_seconds_and_at_the_end(monkeypatch):
    monkeypatch.delenv(EVERY_VARIABLE, raising=False)
    clock, out = Clock(), io.StringIO()
    bar = Progress(None, desc="matching", unit="edge", total=15_630, stream=out, clock=clock)
    for _ in range(4_200):  # 41 s of work, one edge every ~10 ms
        clock.now += 41 / 4_200
        bar.update()
    lines = out.getvalue().splitlines()
    # Lines at 10, 20, 30 and 40 s: never closer than ten seconds apart.
    assert len(lines) == 4, lines
    assert lines[0].startswith("matching: 1,0") and "edges (7%) 10 s, about 2 min " in lines[0]
    bar.set_postfix(loops=12, kept=10)
    bar.close()
    bar.close()  # once only
    last = out.getvalue().splitlines()[-1]
    assert re.fullmatch(
        r"matching: 4,200/15,630 edges \(27%\) 41 s, about 1 min 5\d s left, "
        r"loops 12, kept 10",
        last,
    ), last
    assert len(out.getvalue().splitlines()) == 5


def test_without_a_total_and_for_inner_loops(monkeypatch):
    monkeypatch.setenv(EVERY_VARIABLE, "0")
    out = io.StringIO()
    with Progress(None, desc="bag.db3", unit="message", total=None, stream=out) as bar:
        bar.update(3)
    assert out.getvalue().splitlines()[-1].startswith("bag.db3: 3 messages ")
    out = io.StringIO()
    inner = Progress(range(3), desc="epoch 1/5", unit="batch", total=None, stream=out, leave=False)
    assert list(inner) == [0, 1, 2]
    # Every update is due at 0 s, but the epoch's own log line says it ended: no closing line.
    assert [line.split(" (")[0] for line in out.getvalue().splitlines()] == [
        "epoch 1/5: 1/3 batches",
        "epoch 1/5: 2/3 batches",
        "epoch 1/5: 3/3 batches",
    ]


def test_a_terminal_gets_a_bar_and_off_means_nothing(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert list(track(range(5), "odometry", "scan")) == list(range(5))
    assert "\r" in terminal.getvalue() and "5/5" in terminal.getvalue()
    quiet = io.StringIO()
    monkeypatch.setattr(sys, "stderr", quiet)
    assert list(track(range(5), "odometry", "scan", enabled=False)) == list(range(5))
    bar = counter(5, "fleet", "log", enabled=False)
    bar.update(5)
    bar.close()
    assert quiet.getvalue() == ""


def test_a_failed_loop_prints_no_closing_line(monkeypatch):
    monkeypatch.setenv(EVERY_VARIABLE, "1000")
    out = io.StringIO()
    with pytest.raises(ValueError), Progress(None, desc="x", unit="y", total=4, stream=out) as bar:
        bar.update()
        raise ValueError
    assert out.getvalue() == ""


def test_every_progress_of_the_package_goes_through_one_function():
    users = []
    for path in PACKAGE.rglob("*.py"):
        if path.name == "progress.py" and path.parent == PACKAGE:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            if any(n.split(".")[0] == "tqdm" for n in names):
                users.append(str(path.relative_to(PACKAGE)))
    assert users == []


def _cli(*args: str | Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("vgm-studio")
    cmd = [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]
    # capture_output: stdout and stderr are pipes, as under CI or `| tee`.
    return subprocess.run(
        [*cmd, *map(str, args)], capture_output=True, text=True, timeout=600, env=env, check=True
    )


def test_a_piped_run_prints_progress_lines_on_stderr(tmp_path):
    env = {**os.environ, EVERY_VARIABLE: "0.5"}
    sim = _cli("simulate", "--out", tmp_path, "--seed", "3", "--preset", "corridor", env=env)
    assert re.search(r"^simulate corridor: (\d+)/\1 scans \(100%\) \d+ s$", sim.stderr, re.M)
    log = next(tmp_path.glob("*.log"))
    made = _cli("candidates", log, "--out", tmp_path / "e.jsonl", env=env)
    matching = [line for line in made.stderr.splitlines() if line.startswith("matching: ")]
    # A run of a few seconds, a line every half second: the count grows to the end line.
    assert len(matching) >= 3, made.stderr
    counts = [int(re.match(r"matching: ([\d,]+)/", m)[1].replace(",", "")) for m in matching]
    assert counts == sorted(counts) and counts[0] < counts[-1]
    assert re.fullmatch(r"matching: (\d+)/\1 edges \(100%\) \d+ s", matching[-1])
    assert "\r" not in made.stderr  # lines, not a bar's carriage returns
    # Unasked, a short loop says only where it ended.
    quiet = {k: v for k, v in os.environ.items() if k != EVERY_VARIABLE}
    again = _cli(
        "simulate", "--out", tmp_path / "b", "--seed", "3", "--preset", "corridor", env=quiet
    )
    assert len(again.stderr.strip().splitlines()) == 1, again.stderr
