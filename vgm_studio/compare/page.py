"""A comparison as the terminal shows it and as a CI summary page takes it (markdown)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from vgm_studio.compare.diff import Comparison, ErrorChange
from vgm_studio.compare.loops import LoopPair
from vgm_studio.compare.rules import Outcome
from vgm_studio.compare.runs import Loop

# Loops listed per table on the page and per kind in the terminal; the counts say how many
# there are in all.
LISTED = 50
LISTED_TEXT = 10


def _num(value: float, unit: str) -> str:
    return f"{value:.4f}" if unit == "m" else f"{value:.3f}"


def _change(e: ErrorChange) -> str:
    share = f" ({e.relative:+.1%})" if math.isfinite(e.relative) and e.base else ""
    return f"{e.delta:+.4f}{share}" if e.unit == "m" else f"{e.delta:+.3f}{share}"


def loop_counts(c: Comparison) -> list[tuple[str, int]]:
    """The loop figures in the order both pages show them."""
    lp = c.loops
    rows = [
        ("loops in the base run", len(c.base.loops)),
        ("loops in the new run", len(c.new.loops)),
        ("matched by scan pair", lp.matched),
        ("newly kept", len(lp.newly_kept)),
        ("newly dropped", len(lp.newly_dropped)),
        ("decisions flipped", len(lp.flipped)),
        ("false loops newly kept", len(lp.new_false)),
        ("right loops newly lost", len(lp.lost_right)),
    ]
    if c.common_keyframes:
        rows.append((f"keyframes moved > {c.config.moved_m:g} m", len(c.moved)))
    return rows


def text_report(c: Comparison, outcomes: Sequence[Outcome] = ()) -> str:
    """The terminal's table: errors, loop counts, the loops that matter most, the rules."""
    lines = [f"{c.base.path} → {c.new.path}: {c.new.subject}"]
    if c.errors:
        lines.append(
            f"{'relation error':<18} {'base':>9} {'new':>9} {'change':>18} {'noise':>8}  verdict"
        )
        for e in c.errors:
            name = f"{e.trajectory} {e.unit}"
            lines.append(
                f"{name:<18} {_num(e.base, e.unit):>9} {_num(e.new, e.unit):>9} "
                f"{_change(e):>18} {_num(e.noise, e.unit):>8}  {e.verdict}"
            )
    else:
        lines.append("relation error: not in both runs (no relations or reference)")
    lines += [f"{name}: {n}" for name, n in loop_counts(c)]
    for title, pairs in (
        ("false loops newly kept", c.loops.new_false),
        ("right loops newly lost", c.loops.lost_right),
    ):
        for p in pairs[:LISTED_TEXT]:
            lines.append(f"  {title}: {_ends(c, p)} ({_why(p)})")
        if len(pairs) > LISTED_TEXT:
            lines.append(f"  … {len(pairs) - LISTED_TEXT} more {title}")
    lines.append("no change" if c.unchanged else "changed")
    for o in outcomes:
        lines.append(f"rule {o.rule.text}: {'holds' if o.holds else 'FAILS'}: {o.detail}")
    return "\n".join(lines)


def _ends(c: Comparison, p: LoopPair) -> str:
    a, b = p.ends
    what = "scans" if c.base.kind == "slam" else "vertices"
    return f"{what} {a}–{b}"


def _why(p: LoopPair) -> str:
    loop = p.new or p.base
    assert loop is not None
    return loop.why or loop.source


def _link(p: LoopPair, studio_url: str | None) -> str:
    if p.edge_id is None:
        return ""
    if studio_url is None:
        return f"`{p.edge_id}`"
    return f"[{p.edge_id}]({studio_url.rstrip('/')}/?edge={p.edge_id})"


def _decision(loop: Loop | None) -> str:
    if loop is None:
        return "not proposed"
    p = "" if loop.p_success is None else f", p {loop.p_success:.2f}"
    return f"{loop.decision}{p}"


def _loop_table(c: Comparison, pairs: list[LoopPair], studio_url: str | None) -> list[str]:
    rows = [
        "| loop | source | base | new | reference | studio |",
        "|---|---|---|---|---|---|",
    ]
    for p in pairs[:LISTED]:
        loop = p.new or p.base
        assert loop is not None
        truth = "" if p.truth is None else f"{p.truth}: {_why(p)}"
        rows.append(
            f"| {_ends(c, p)} | {loop.source} | {_decision(p.base)} | {_decision(p.new)} "
            f"| {truth} | {_link(p, studio_url)} |"
        )
    if len(pairs) > LISTED:
        rows.append(f"\n{len(pairs) - LISTED} more not listed.")
    return rows


def markdown(
    c: Comparison,
    outcomes: Sequence[Outcome] = (),
    picture: Path | None = None,
    studio_url: str | None = None,
) -> str:
    """The comparison as a page: rules, errors, loop counts and tables, moved keyframes, the
    overlay picture; each listed loop links to the studio with ``studio_url``."""
    failed = [o for o in outcomes if not o.holds]
    verdict = "no change" if c.unchanged else "changed"
    if outcomes:
        verdict += "; rules: " + ("all hold" if not failed else f"{len(failed)} failed")
    lines = [
        f"# Compare: `{c.base.path.name}` → `{c.new.path.name}`",
        "",
        f"{c.new.kind} runs of `{c.new.subject}`: **{verdict}**",
        "",
    ]
    if outcomes:
        lines += ["| rule | | figure |", "|---|---|---|"]
        lines += [
            f"| `{o.rule.text}` | {'holds' if o.holds else '**fails**'} | {o.detail} |"
            for o in outcomes
        ]
        lines.append("")
    lines += ["## Relation error", ""]
    if c.errors:
        lines += [
            "| trajectory | base | new | change | noise | verdict |",
            "|---|---|---|---|---|---|",
        ]
        for e in c.errors:
            lines.append(
                f"| {e.trajectory} ({e.unit}) | {_num(e.base, e.unit)} | {_num(e.new, e.unit)} "
                f"| {_change(e)} | ±{_num(e.noise, e.unit)} | {e.verdict} |"
            )
        n = c.config.noise
        lines += [
            "",
            f"Noise: {n.floor_m:g} m (rotation {n.floor_deg:g}°) + {n.share:.0%} of the base "
            "error, from the nudged spread in BENCHMARKS.md (`--noise`).",
        ]
    else:
        lines.append("Not in both runs (no relations or reference poses).")
    lines += ["", "## Loops", "", "| | count |", "|---|---|"]
    lines += [f"| {name} | {n} |" for name, n in loop_counts(c)]
    lines.append("")
    for title, pairs in (
        ("False loops newly kept", c.loops.new_false),
        ("Right loops newly lost", c.loops.lost_right),
        ("Decisions flipped", c.loops.flipped),
        ("Newly kept", c.loops.newly_kept),
        ("Newly dropped", c.loops.newly_dropped),
    ):
        if pairs:
            lines += [f"### {title} ({len(pairs)})", "", *_loop_table(c, pairs, studio_url), ""]
    if c.moved:
        lines += [
            f"## Keyframes moved ({len(c.moved)} of {c.common_keyframes} at the same scan)",
            "",
            "| scan | moved m | turned ° |",
            "|---|---|---|",
        ]
        lines += [f"| {m.scan} | {m.metres:.3f} | {m.degrees:.2f} |" for m in c.moved[:LISTED]]
        lines.append("")
    if picture is not None:
        lines += ["## After maps", "", f"![after maps, base and new]({picture.as_posix()})", ""]
    return "\n".join(lines)
