"""``vgm-studio fleet``: candidates, validation and a SLAM summary for every log of a manifest."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.datasets import ReadOptions
from vgm_studio.model.registry import VALIDATOR_MODELS
from vgm_studio.tools.options import (
    MaxLoopsOpt,
    TimeToleranceOpt,
    non_negative,
    number,
    one_of,
    positive,
    with_read_options,
    writable_folder,
)
from vgm_studio.tools.slam_cmd import RobustChoice


@with_read_options
def fleet(
    manifest: Annotated[
        Path,
        typer.Argument(
            metavar="MANIFEST.jsonl",
            help='One JSON object per line: {"log": PATH, "reference": PATH, "relations": '
            'PATH, "name": NAME}; only "log" is required; paths relative to the manifest.',
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            metavar="DIR", help="Folder for fleet.parquet, the map grid and one folder per log."
        ),
    ],
    read: ReadOptions,
    ray_address: Annotated[
        str | None,
        typer.Option(
            metavar="ADDR",
            help="An existing Ray cluster (HOST:6379 or ray://HOST:10001).",
            show_default="start a local Ray on this machine",
        ),
    ] = None,
    num_cpus: Annotated[
        int | None,
        typer.Option(help="CPUs of the local Ray.", min=1, show_default="all of them"),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(help="Workers, one CPU each.", min=1, show_default="one per CPU"),
    ] = None,
    ray_temp_dir: Annotated[
        Path | None,
        typer.Option(metavar="DIR", help="The local Ray's session folder (keep it short)."),
    ] = None,
    validator: Annotated[
        str,
        one_of(tuple(VALIDATOR_MODELS), "The model that validates candidates and SLAM edges."),
    ] = "vgmnet",
    model: Annotated[
        Path | None,
        typer.Option(
            metavar="MODEL.pt",
            help="Its checkpoint.",
            show_default="assets/models/vgmnet-default.pt for vgmnet",
        ),
    ] = None,
    loop_threshold: Annotated[
        float,
        typer.Option(
            help="p(success) a SLAM loop edge needs, in [0, 1] (as slam's option).",
            callback=number(0, 1),
        ),
    ] = 0.8,
    robust: Annotated[
        RobustChoice, typer.Option(help="SLAM back end: none, huber or gnc (as slam's option).")
    ] = RobustChoice.none,
    keyframe_distance: Annotated[
        float, positive("SLAM: a keyframe every this many metres (> 0).")
    ] = 0.5,
    candidate_keyframes: Annotated[
        float,
        non_negative(
            "Candidates: a keyframe every this many metres (candidates --keyframe-distance; "
            "0: every scan)."
        ),
    ] = 0.5,
    max_loops: MaxLoopsOpt = 2000,
    time_tolerance: TimeToleranceOpt = 0.05,
) -> None:
    """Candidates, validation and a SLAM summary for every log of a manifest, on Ray.

    Logs already done with the same settings are skipped; a log that fails is a failed row.
    """
    from vgm_studio.datasets.source import JoinOptions
    from vgm_studio.graph.config import GraphConfig
    from vgm_studio.matching.candidates import CandidateConfig
    from vgm_studio.services.fleet import RayOptions, run_fleet
    from vgm_studio.services.fleet_log import FleetSettings
    from vgm_studio.services.slam import validator_model
    from vgm_studio.slam.config import FrontEndConfig, SlamConfig, ValidationConfig

    writable_folder(out)
    chosen = validator_model(validator, model)
    assert chosen is not None  # every model validator has a checkpoint or asks for one
    settings = FleetSettings(
        slam=SlamConfig(
            front_end=FrontEndConfig(keyframe_distance=keyframe_distance),
            validation=ValidationConfig(
                validator=validator, model=chosen, loop_threshold=loop_threshold or None
            ),
            graph=GraphConfig(robust=robust.value),
        ),
        candidates=CandidateConfig(keyframe_distance=candidate_keyframes, max_loops=max_loops),
        read=read,
        join=JoinOptions(time_tolerance),
    )
    run = run_fleet(
        manifest,
        out,
        settings,
        RayOptions(ray_address, num_cpus, workers, ray_temp_dir),
        say=lambda line: typer.echo(line, err=True),
    )
    for line in run.lines():
        typer.echo(line)
    if any(r["status"] != "done" for r in run.rows):
        raise SystemExit(3)  # some logs failed: the table says which
