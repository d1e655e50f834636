"""``vgm-studio audit``: judge every edge of another SLAM's pose graph, and write the cleaned
graph, its maps, a recording, the report and the flagged edges for the studio."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vgm_studio.atomic import write_text_atomically
from vgm_studio.audit import (
    AuditConfig,
    AuditInput,
    AuditResult,
    by_index,
    by_times,
    inline_input,
    run_audit,
)
from vgm_studio.audit.report import audit_line, audit_markdown, audit_summary
from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.datasets.g2o import read_graph
from vgm_studio.datasets.source import JoinOptions, LogSource, attach_reference
from vgm_studio.datasets.tum import TumTrajectory, read_tum
from vgm_studio.errors import InputError
from vgm_studio.matching.edges import write_edges
from vgm_studio.services import Voice
from vgm_studio.services.outputs import RunFiles, write_json, write_run_files
from vgm_studio.slam.loop_edges import loop_edges
from vgm_studio.slam.report import errors_of, table
from vgm_studio.slam.scoring import score_by_reference


@dataclass(frozen=True)
class AuditSources:
    """Where the graph, its scans and its reference come from.

    Attributes:
        graph: A g2o 2D or TORO graph.
        scans: A log or bag with the vertices' scans (else the graph's own ROBOTLASER1).
        vertex_times: A TUM file, one line per vertex, tying each to the scan at its time.
        vertex_index: Vertex id = scan index in ``scans``.
        read: How ``scans`` is read.
        reference: Reference poses (a corrected log, TRUEPOS) joined to the scans.
        relations: A Freiburg relations file matched to the scans.
        join: Timestamp tolerance (the vertex times' too) and offset.
    """

    graph: Path
    scans: Path | None = None
    vertex_times: Path | None = None
    vertex_index: bool = False
    read: ReadOptions = field(default_factory=ReadOptions)
    reference: Path | None = None
    relations: Path | None = None
    join: JoinOptions = field(default_factory=JoinOptions)


@dataclass(frozen=True)
class AuditOutputs:
    """What an audit writes besides its lines.

    Attributes:
        json: The report: totals, errors and every edge.
        markdown: The report as a page for a person (or a CI summary).
        edges: The flagged edges as an edges file ``vgm-studio label`` opens.
        files: Maps, recording, trajectory, ROS map and the cleaned graph (``--g2o``).
    """

    json: Path | None = None
    markdown: Path | None = None
    edges: Path | None = None
    files: RunFiles = field(default_factory=RunFiles)


def read_audit_input(sources: AuditSources) -> tuple[AuditInput, LogSource]:
    """Reads the graph, ties its vertices to scans, and joins the reference.

    Raises:
        InputError: Any input is missing or malformed, or the vertices cannot be tied.
    """
    graph = read_graph(sources.graph)
    if sources.scans is None:
        if sources.vertex_times is not None or sources.vertex_index:
            raise InputError(None, "--vertex-times and --vertex-index tie vertices to --scans")
        inp = inline_input(graph)
    else:
        if sources.vertex_times is not None and sources.vertex_index:
            raise InputError(None, "give --vertex-times or --vertex-index, not both")
        times = None if sources.vertex_times is None else read_tum(sources.vertex_times)
        log = open_log(sources.scans, sources.read)
        if sources.vertex_index:
            inp = by_index(graph, log)
        elif times is not None and sources.vertex_times is not None:
            tolerance = sources.join.time_tolerance
            inp = by_times(graph, log, times, sources.vertex_times, tolerance)
        elif graph.scans is not None and np.all(np.isfinite(graph.timestamps)):
            # The graph's own scans carry their times: each vertex takes the log's scan then.
            own = TumTrajectory(graph.timestamps, graph.poses, graph.lines)
            inp = by_times(graph, log, own, graph.path, sources.join.time_tolerance)
        else:
            raise InputError(
                sources.scans,
                "which scan is which vertex? give --vertex-times FILE (a TUM file of the "
                "vertices' times) or --vertex-index scan (vertex id = scan index)",
            )
    params: dict[str, Any] = {"read": asdict(sources.read), "reference_source": "log"}
    source = LogSource(inp.log, None, params)
    attach_reference(source, sources.read, sources.reference, sources.relations, sources.join)
    score_by_reference(source)
    inp.log = source.log
    return inp, source


def run_audit_command(
    sources: AuditSources,
    config: AuditConfig,
    outputs: AuditOutputs | None = None,
    voice: Voice | None = None,
) -> dict[str, Any]:
    """Reads, audits, scores against the reference and writes what ``outputs`` asks.

    Returns:
        The ``--json`` document (written or not).

    Raises:
        InputError: The inputs cannot be read or an output cannot be written.
    """
    start = time.perf_counter()
    outputs = outputs or AuditOutputs()
    voice = voice or Voice()
    inp, source = read_audit_input(sources)
    for line in source.warnings:
        voice.warn(line)
    voice.say(
        f"{sources.graph}: {len(inp.graph):,} vertices, {len(inp.graph.edges):,} edges, "
        f"scans from {inp.log.path}"
    )
    result = run_audit(inp, config)
    voice.say(audit_line(result))
    errors = errors_of(result.run, source.relations)
    if errors is not None:
        voice.say(table(errors))
    write_run_files(inp.log, result.run, errors, config.maps, outputs.files, voice)
    if outputs.edges is not None:
        _write_flagged(outputs.edges, result, source, voice)
    seconds = time.perf_counter() - start
    settings = json.loads(json.dumps(asdict(config), default=str))
    doc = audit_summary(result, errors, settings, seconds)
    if outputs.json is not None:
        write_json(outputs.json, doc)
        voice.say(f"wrote {outputs.json}")
    if outputs.markdown is not None:
        _write_markdown(outputs.markdown, doc, outputs.files.maps)
        voice.say(f"wrote {outputs.markdown}")
    voice.say(f"done in {seconds:.1f} s")
    return doc


def _write_flagged(path: Path, result: AuditResult, source: LogSource, voice: Voice) -> None:
    flagged = [v for v in result.verdicts if v.decision == "flagged"]
    edges = loop_edges(source.log, result.run, source.params, chosen=[v.edge for v in flagged])
    for edge, v in zip(edges, flagged, strict=True):
        edge.match["audit"] = {"reason": v.reason, "injected": v.edge.injected}
    write_edges(path, edges)
    voice.say(f"wrote {len(edges)} flagged edges to {path} (open it with vgm-studio label)")


def _write_markdown(path: Path, doc: dict[str, Any], maps: Path | None) -> None:
    pictures = []
    if maps is not None:
        for name in ("side-by-side", "edges"):
            picture = maps / f"{name}.png"
            if picture.exists():
                pictures.append(Path(_relative(picture, path.parent)))
    try:
        write_text_atomically(path, audit_markdown(doc, pictures))
    except OSError as exc:
        raise InputError(path, f"cannot write ({exc.strerror or exc})") from None


def _relative(target: Path, base: Path) -> str:
    try:
        return str(target.resolve().relative_to(base.resolve()))
    except ValueError:
        return str(target.resolve())
