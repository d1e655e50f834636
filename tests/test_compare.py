"""``vgm-studio compare`` on real runs of the bundled demo log, and docs/ci.md's workflow played
through with bash."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import pytest

from vgm_studio.compare import parse_rules
from vgm_studio.compare.loops import changes, match_loops
from vgm_studio.compare.overlay import coloured_cells
from vgm_studio.compare.runs import Loop
from vgm_studio.errors import InputError
from vgm_studio.tools import cmd

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "datasets" / "demo-seed0.log"
RULES = "error-increase=10%,new-false-loops=0"


def slam(*args: str | Path) -> None:
    cmd.main(["slam", *map(str, args)])


def compare(capsys, *args: str | Path) -> tuple[int, str, str]:
    """Runs ``vgm-studio compare`` in this process: exit status, stdout, stderr."""
    capsys.readouterr()
    try:
        cmd.main(["compare", *map(str, args)])
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """Two runs of the demo log as they stand, and one that keeps injected false loops
    (no validator and no consistency check: with them the run keeps none of the five)."""
    out = tmp_path_factory.mktemp("runs")
    slam(DEMO, "--json", out / "base.json")
    slam(DEMO, "--json", out / "again.json")
    slam(
        DEMO, "--inject-false-loops", "5", "--validator", "none", "--consistency", "none",
        "--json", out / "injected.json",
    )  # fmt: skip
    return {name: out / f"{name}.json" for name in ("base", "again", "injected")}


def _kept_injected(path: Path) -> list[tuple[int, int]]:
    doc = json.loads(path.read_text())
    return [
        tuple(sorted((e["scan_a"], e["scan_b"])))
        for e in doc["edges"]
        if e["source"] == "injected" and e["kept"]
    ]


def test_two_runs_of_one_log_show_no_change_and_exit_0(runs, capsys, tmp_path):
    code, out, err = compare(
        capsys, runs["base"], runs["again"], "--fail-on", RULES,
        "--png", tmp_path / "same.png", "--markdown", tmp_path / "same.md",
    )  # fmt: skip
    assert code == 0, err
    assert "no change" in out
    assert re.search(r"newly kept: 0\b", out) and re.search(r"decisions flipped: 0\b", out)
    assert "holds" in out and "FAILS" not in out
    # Identical after maps: no wall in either run's own colour.
    assert coloured_cells(cv2.imread(str(tmp_path / "same.png"))) == {"base": 0, "new": 0}
    assert "**no change; rules: all hold**" in (tmp_path / "same.md").read_text()


def test_kept_injected_loops_fail_the_rules_and_are_named(runs, capsys):
    injected = _kept_injected(runs["injected"])
    assert injected, "the run kept no injected loop: nothing to name"
    code, out, err = compare(capsys, runs["base"], runs["injected"], "--fail-on", RULES)
    assert code == 1
    assert "vgm-studio compare: failed: new-false-loops=0" in err
    assert "vgm-studio compare: failed: error-increase=10%" in err
    for a, b in injected:
        # Injected loops are listed first, so the terminal's ten show them all.
        assert f"false loops newly kept: scans {a}–{b} (injected)" in out
    # A rule the change keeps holds, and only the failed rule is printed.
    code, _, err = compare(capsys, runs["base"], runs["injected"], "--fail-on", "newly-kept=1000")
    assert code == 0 and err == ""


def test_the_markdown_links_each_flipped_loop_to_the_studio(runs, capsys, tmp_path):
    page = tmp_path / "cmp.md"
    url = "http://studio.test:8123"
    code, _, _ = compare(
        capsys, runs["base"], runs["injected"], "--markdown", page, "--studio-url", url + "/",
        "--png", tmp_path / "cmp.png",
    )  # fmt: skip
    assert code == 0  # no rules given: nothing fails
    text = page.read_text()
    flipped = re.search(r"### Decisions flipped \((\d+)\)\n\n(.*?)\n\n", text, re.S)
    assert flipped is not None and int(flipped.group(1)) > 0
    rows = flipped.group(2).splitlines()[2:]
    assert len(rows) == min(int(flipped.group(1)), 50)
    ids = {
        e["edge_id"] for e in json.loads(runs["injected"].read_text())["edges"] if "edge_id" in e
    }
    for row in rows:
        link = re.search(rf"\[([0-9a-f]{{16}})\]\({re.escape(url)}/\?edge=([0-9a-f]{{16}})\)", row)
        assert link is not None and link.group(1) == link.group(2) and link.group(1) in ids, row
    assert "![after maps, base and new](cmp.png)" in text
    after = json.loads(runs["base"].read_text())["after"]["trans_mean"]
    # The default noise: 2 mm and a tenth of the base's after error.
    assert "| false loops newly kept |" in text and f"±{0.002 + 0.1 * after:.4f}" in text


def test_the_picture_differs_where_the_maps_differ(runs, capsys, tmp_path):
    png = tmp_path / "diff.png"
    code, _, _ = compare(capsys, runs["base"], runs["injected"], "--png", png)
    assert code == 0
    image = cv2.imread(str(png))
    cells = coloured_cells(image)
    # The bent map puts walls where the base has none, and leaves the base's walls bare.
    assert cells["base"] > 200 and cells["new"] > 200, cells


def test_keyframes_that_moved_are_counted(runs, capsys):
    _, out, _ = compare(capsys, runs["base"], runs["injected"])
    moved = int(re.search(r"keyframes moved > 0.1 m: (\d+)", out).group(1))  # type: ignore[union-attr]
    assert moved > 10
    _, out, _ = compare(capsys, runs["base"], runs["again"], "--moved", "0.001")
    assert "keyframes moved > 0.001 m: 0" in out


def test_rules_parse_and_refuse_what_they_do_not_know():
    rules = parse_rules("error-increase=10%, new-false-loops=0,rot-error-increase=noise")
    assert [(r.name, r.limit, r.relative, r.noise) for r in rules] == [
        ("error-increase", pytest.approx(0.10), True, False),
        ("new-false-loops", 0.0, False, False),
        ("rot-error-increase", 0.0, False, True),
    ]
    assert parse_rules("error-increase=0.005")[0].relative is False
    assert parse_rules("") == []
    for bad, words in (
        ("error-rise=1", "unknown rule 'error-rise'"),
        ("new-false-loops", "needs a limit"),
        ("new-false-loops=1.5", "whole count"),
        ("error-increase=-1%", "at least 0"),
        ("flipped=noise", "a count"),
    ):
        with pytest.raises(InputError, match=re.escape(words)):
            parse_rules(bad)


def _loop(a: int, b: int, kept: bool, truth: str | None = None) -> Loop:
    return Loop(a, b, kept, "kept" if kept else "rejected", "kept", "window", 0.9, truth)


def test_loops_are_matched_by_scan_pair_within_the_tolerance():
    base = [_loop(10, 100, True, "right"), _loop(40, 300, False), _loop(50, 500, True)]
    new = [_loop(12, 98, True), _loop(41, 301, True, "false"), _loop(50, 500, True)]
    c = changes(match_loops(base, new, tolerance=2))
    assert c.matched == 3 and c.flipped and len(c.newly_kept) == 1 and not c.newly_dropped
    assert [p.ends for p in c.new_false] == [(41, 301)]
    # Within one scan the first loop's ends no longer meet: dropped there, kept anew here.
    c = changes(match_loops(base, new, tolerance=1))
    assert c.matched == 2 and c.base_only == 1 and c.new_only == 1
    assert [p.ends for p in c.lost_right] == [(10, 100)]


def test_every_bad_input_is_one_line_and_exit_2(runs, capsys, tmp_path):
    base = runs["base"]
    doc = json.loads(base.read_text())
    other_log = tmp_path / "other.json"
    other_log.write_text(json.dumps({**doc, "log": {**doc["log"], "sha256": "0" * 64}}))
    old = tmp_path / "old.json"
    old.write_text(json.dumps({k: v for k, v in doc.items() if k != "log"}))
    (tmp_path / "not.json").write_text("{ not json")
    (tmp_path / "list.json").write_text("[1, 2]")
    audit = tmp_path / "audit.json"
    audit.write_text(json.dumps({"graph": "g.g2o", "vertices": 3, "edges": []}))
    moved_log = tmp_path / "demo-copy.log"
    moved_log.write_text(DEMO.read_text() + "# a comment\n")
    missing = tmp_path / "missing.json"
    for args, expected in (
        ((base, missing), f"{missing}: no such file"),
        ((tmp_path / "not.json", base), f"{tmp_path / 'not.json'}: not JSON"),
        ((base, tmp_path / "list.json"), f"{tmp_path / 'list.json'}: not a run"),
        ((base, other_log), f"{other_log}: a run of demo-seed0.log (sha256 000000000000)"),
        ((base, old), f"{old}: this slam run does not name its log"),
        ((base, audit), f"{audit}: an audit run, but {base} is a slam run"),
        ((base, base, "--fail-on", "speed=1"), "--fail-on: unknown rule 'speed'"),
        (
            (base, base, "--png", tmp_path / "x.png", "--log", moved_log),
            f"{moved_log}: not the log the runs read",
        ),
        (
            (base, base, "--png", tmp_path / "x.png", "--log", tmp_path / "gone.log"),
            f"{tmp_path / 'gone.log'}: the runs' log is not here",
        ),
    ):
        code, _, err = compare(capsys, *args)
        lines = err.strip().splitlines()
        assert code == 2, (args, err)
        assert len(lines) == 1 and lines[0].startswith(f"vgm-studio: error: {expected}"), lines
    assert not (tmp_path / "x.png").exists()


def _workflow_steps() -> dict[str, str]:
    yaml = pytest.importorskip("yaml")
    text = (REPO / "docs" / "ci.md").read_text()
    block = re.search(r"```yaml\n(.*?)```", text, re.S)
    assert block is not None
    job = yaml.safe_load(block.group(1))["jobs"]["slam"]
    assert "GITHUB_STEP_SUMMARY" in block.group(1)
    upload = next(s for s in job["steps"] if "upload-artifact" in s.get("uses", ""))
    assert upload["if"] == "always()" and "out/run.rrd" in upload["with"]["path"]
    assert "out/compare.md" in upload["with"]["path"]
    steps = {s["name"]: s["run"] for s in job["steps"] if "run" in s}
    return {"env": job["env"], **steps}  # type: ignore[dict-item]


@pytest.mark.long
@pytest.mark.skipif(shutil.which("vgm-studio") is None, reason="vgm-studio not on PATH")
def test_the_ci_recipe_plays_through(runs, tmp_path):
    steps = _workflow_steps()
    env = {**os.environ, **steps["env"]}  # type: ignore[dict-item]
    summary = tmp_path / "summary.md"
    env.update(
        LOG=str(DEMO), BASELINE=str(runs["base"]), OUT=str(tmp_path / "out"),
        GITHUB_STEP_SUMMARY=str(summary),
    )  # fmt: skip

    def step(name: str) -> subprocess.CompletedProcess[str]:
        # As GitHub runs a step: bash -e, in the repository.
        return subprocess.run(
            ["bash", "-e", "-c", steps[name]], env=env, cwd=REPO, capture_output=True, text=True
        )

    ran = step("SLAM run")
    assert ran.returncode == 0, ran.stderr[-2000:]
    assert (tmp_path / "out" / "run.rrd").stat().st_size > 0
    same = step("Compare with the baseline")
    assert same.returncode == 0, same.stderr[-2000:]
    assert "no change" in summary.read_text()
    # The run that kept injected false loops in the new run's place: the job fails.
    shutil.copy(runs["injected"], tmp_path / "out" / "run.json")
    worse = step("Compare with the baseline")
    assert worse.returncode == 1
    assert "failed: new-false-loops=0" in worse.stderr
    page = summary.read_text()
    assert page.count("# Compare:") == 2  # appended, not overwritten
    for a, b in _kept_injected(runs["injected"]):
        assert f"| scans {a}–{b} | injected |" in page
    assert (tmp_path / "out" / "compare.png").stat().st_size > 0
