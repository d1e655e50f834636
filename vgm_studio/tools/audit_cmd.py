"""``vgm-studio audit``: judge every edge of another SLAM's pose graph."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.datasets import ReadOptions
from vgm_studio.tools.options import TimeToleranceOpt, number, with_read_options
from vgm_studio.tools.run_options import (
    G2oOpt,
    InjectOpt,
    InjectSeedOpt,
    JsonOutOpt,
    LoopThresholdOpt,
    MapPngOpt,
    ModelOpt,
    RecordOpt,
    ReferenceOpt,
    RelationsOpt,
    ResolutionOpt,
    RosMapOpt,
    SpawnOpt,
    TimeOffsetOpt,
    TrajectoryOpt,
    check_writable,
    run_files,
    validator_option,
)


class VertexIndex(str, Enum):
    scan = "scan"


@with_read_options
def audit(
    graph: Annotated[
        Path,
        typer.Argument(
            metavar="GRAPH",
            help="A g2o 2D graph (VERTEX_SE2, EDGE_SE2, FIX, with or without ROBOTLASER1 "
            "scans) or a TORO / MRPT .graph (VERTEX2, EDGE2).",
        ),
    ],
    read: ReadOptions,
    scans: Annotated[
        Path | None,
        typer.Option(
            metavar="LOG_OR_BAG",
            help="The log or bag with the vertices' scans (needed when the graph has no "
            "ROBOTLASER1 lines); tie them with --vertex-times or --vertex-index.",
        ),
    ] = None,
    vertex_times: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="A TUM file with one line per vertex, in the order of their ids: each vertex "
            "takes the scan nearest its timestamp (within --time-tolerance).",
        ),
    ] = None,
    vertex_index: Annotated[
        VertexIndex | None,
        typer.Option(help="'scan': vertex id = the scan's index in --scans."),
    ] = None,
    validator: Annotated[
        str,
        validator_option(
            "Who judges the edges: a model (vgmnet, rgb-baseline, score; see --model), "
            "reference (edges that land on the reference pose) or none (keep all)."
        ),
    ] = "vgmnet",
    model: ModelOpt = None,
    loop_threshold: LoopThresholdOpt = 0.8,
    flag_below: Annotated[
        float | None,
        typer.Option(
            help="An edge whose p(success) is under this is a failure of its scans, in "
            "[0, 1]; a loop between it and --loop-threshold is unsure and kept unless the "
            "group check rejects it.",
            show_default="the checkpoint's threshold",
            callback=number(0, 1, optional=True),
        ),
    ] = None,
    inject_false_loops: InjectOpt = 0,
    seed: InjectSeedOpt = 0,
    reference: ReferenceOpt = None,
    relations: RelationsOpt = None,
    time_offset: TimeOffsetOpt = 0.0,
    time_tolerance: TimeToleranceOpt = 0.05,
    json_out: JsonOutOpt = None,
    markdown: Annotated[
        Path | None,
        typer.Option(metavar="OUT.md", help="Write the report as a page for a person or CI."),
    ] = None,
    edges_out: Annotated[
        Path | None,
        typer.Option(
            metavar="OUT.jsonl",
            help="Write the flagged edges as an edges file: vgm-studio label opens it.",
        ),
    ] = None,
    g2o: G2oOpt = None,
    map_png: MapPngOpt = None,
    ros_map: RosMapOpt = None,
    trajectory: TrajectoryOpt = None,
    record: RecordOpt = None,
    spawn: SpawnOpt = False,
    resolution: ResolutionOpt = 0.05,
) -> None:
    """Judge every edge of another SLAM's pose graph from its scans; write the cleaned graph."""
    from vgm_studio.audit import AuditConfig, InjectConfig
    from vgm_studio.datasets.source import JoinOptions
    from vgm_studio.maps.config import MapConfig
    from vgm_studio.services import Voice
    from vgm_studio.services.audit import AuditOutputs, AuditSources, run_audit_command
    from vgm_studio.services.slam import validator_model
    from vgm_studio.slam.config import ValidationConfig

    check_writable([json_out, markdown, edges_out])
    files = run_files(map_png, record, spawn, trajectory, ros_map, g2o)
    config = AuditConfig(
        validation=ValidationConfig(
            validator=validator,
            model=validator_model(validator, model),
            loop_threshold=loop_threshold or None,
        ),
        maps=MapConfig(resolution=resolution),
        inject=InjectConfig(count=inject_false_loops, seed=seed),
        flag_below=flag_below,
    )
    run_audit_command(
        AuditSources(
            graph,
            scans,
            vertex_times,
            vertex_index is not None,
            read,
            reference,
            relations,
            JoinOptions(time_tolerance, time_offset),
        ),
        config,
        AuditOutputs(json_out, markdown, edges_out, files),
        Voice(typer.echo, lambda line: typer.echo(line, err=True)),
    )
