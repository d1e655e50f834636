"""``vgm-studio demo``: the whole foundation pipeline on the bundled demo log."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import asdict
from pathlib import Path

import typer

from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.errors import InputError
from vgm_studio.matching.candidates import make_candidates
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import write_edges
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.tools.info import format_summary, summarize
from vgm_studio.vgm.picture import edge_picture


def run_demo(log_path: Path, out: Path) -> None:
    """Reads the demo log, makes and labels its candidate edges, draws one of each label."""
    if not log_path.exists():
        raise InputError(
            log_path,
            "bundled demo log missing; remake it with the command in "
            "README.md (vgm-studio simulate --out datasets --preset demo --seed 0)",
        )
    options = ReadOptions()
    log = open_log(log_path, options)
    typer.echo(format_summary(summarize(log)))
    typer.echo("")
    start = time.perf_counter()
    edges = make_candidates(
        log, ScanMatcher(), params={"read": asdict(options), "reference_source": "log"}
    )
    seconds = time.perf_counter() - start
    out.mkdir(parents=True, exist_ok=True)
    edges_path = out / "edges.jsonl"
    write_edges(edges_path, edges)
    counts = Counter(e.label or "unlabelled" for e in edges)
    typer.echo(f"{len(edges)} candidate edges in {seconds:.1f} s → {edges_path}")
    typer.echo("labels: " + ", ".join(f"{k} {v}" for k, v in counts.most_common()))
    scans = EdgeScans()
    for label in ("success", "failure"):
        loops = [e for e in edges if e.label == label and e.kind == "loop"]
        if loops:
            png = out / f"vgm-{label}.png"
            edge_picture(loops[len(loops) // 2], png, scans=scans)
            typer.echo(f"a {label} edge, drawn: {png}")
    typer.echo(f"next: vgm-studio vgm {edges_path} --edge <edge_id> --png edge.png")
