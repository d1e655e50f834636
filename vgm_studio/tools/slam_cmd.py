"""``vgm-studio slam``: a whole graph-SLAM run with validated edges, maps, metrics, a recording."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.datasets import ReadOptions
from vgm_studio.slam.config import VALIDATORS
from vgm_studio.tools.options import (
    LogArg,
    TimeToleranceOpt,
    number,
    one_of,
    positive,
    with_read_options,
)
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
)


class RobustChoice(str, Enum):
    none = "none"
    huber = "huber"
    gnc = "gnc"


class ConsistencyChoice(str, Enum):
    pcm = "pcm"
    none = "none"


@with_read_options
def slam(
    log: LogArg,
    read: ReadOptions,
    validator: Annotated[
        str,
        one_of(
            VALIDATORS,
            "Which edges enter the graph: none (all), a model (vgmnet, rgb-baseline, "
            "score; see --model) or reference (edges that land on the reference pose).",
        ),
    ] = "vgmnet",
    model: ModelOpt = None,
    loop_threshold: LoopThresholdOpt = 0.8,
    loop_precision: Annotated[
        float,
        typer.Option(
            help="Loop edges also need the p(success) cut at which the model's validation "
            "precision reaches this, in [0, 1] (e.g. 0.99); with --loop-threshold the higher "
            "cut wins (0: off).",
            callback=number(0, 1),
        ),
    ] = 0.0,
    second_look: Annotated[
        int,
        typer.Option(
            help="A model validator looks again at the edges it is unsure of (p between "
            "0.02 and 0.98), its logits averaged over the pair turned this many ways "
            "(1: off; e.g. 4).",
            min=1,
        ),
    ] = 1,
    robust: Annotated[
        RobustChoice,
        typer.Option(help="Back-end outlier handling: none, huber kernels, or gnc (TLS)."),
    ] = RobustChoice.none,
    consistency: Annotated[
        ConsistencyChoice,
        typer.Option(
            help="Group check of the loops the validator kept: pcm (pairwise consistency "
            "maximisation) or none."
        ),
    ] = ConsistencyChoice.pcm,
    reference: ReferenceOpt = None,
    time_offset: TimeOffsetOpt = 0.0,
    time_tolerance: TimeToleranceOpt = 0.05,
    relations: RelationsOpt = None,
    json_out: JsonOutOpt = None,
    map_png: MapPngOpt = None,
    ros_map: RosMapOpt = None,
    trajectory: TrajectoryOpt = None,
    g2o: G2oOpt = None,
    record: RecordOpt = None,
    spawn: SpawnOpt = False,
    loops_out: Annotated[
        Path | None,
        typer.Option(
            metavar="OUT.jsonl",
            help="Write the loops the run matched as an edges file, with its decisions and "
            "reference labels: open it in the studio, or train on it.",
        ),
    ] = None,
    loops_injected: Annotated[
        bool,
        typer.Option(
            "--loops-injected",
            help="With --loops-out and --inject-false-loops: write the injected false loops "
            "too (source injected), to see in the studio what the run made of them.",
        ),
    ] = False,
    keyframe_distance: Annotated[float, positive("Keyframe every this many metres (> 0).")] = 0.5,
    keyframe_angle: Annotated[float, positive("…or this many degrees (> 0).")] = 20.0,
    loop_radius: Annotated[
        float,
        positive(
            "Loop candidates within this many metres of the estimate where the graph is sure "
            "(> 0); the window grows with its uncertainty."
        ),
    ] = 3.0,
    loop_min_gap: Annotated[
        int, typer.Option(help="Loop candidates at least this many keyframes back.", min=1)
    ] = 20,
    loops_per_keyframe: Annotated[
        int, typer.Option(help="Nearest loop candidates matched per keyframe.", min=0)
    ] = 2,
    final_sweep: Annotated[
        bool,
        typer.Option(
            help="After the last keyframe, search once more, from the final estimate, the "
            "revisits no kept loop closes."
        ),
    ] = True,
    resolution: ResolutionOpt = 0.05,
    inject_false_loops: InjectOpt = 0,
    seed: InjectSeedOpt = 0,
) -> None:
    """Graph SLAM with validated edges: odometry, loops, gtsam, maps, metrics, a recording."""
    from vgm_studio.datasets.source import JoinOptions
    from vgm_studio.graph.config import GraphConfig
    from vgm_studio.maps.config import MapConfig
    from vgm_studio.services import Voice
    from vgm_studio.services.slam import SlamOutputs, run_slam_command, validator_model
    from vgm_studio.slam.config import (
        ConsistencyConfig,
        FrontEndConfig,
        SlamConfig,
        ValidationConfig,
    )

    check_writable([json_out, loops_out])
    files = run_files(map_png, record, spawn, trajectory, ros_map, g2o)
    config = SlamConfig(
        front_end=FrontEndConfig(
            keyframe_distance=keyframe_distance,
            keyframe_angle_deg=keyframe_angle,
            loop_radius=loop_radius,
            loop_min_gap=loop_min_gap,
            loops_per_keyframe=loops_per_keyframe,
            final_sweep=final_sweep,
            false_loops=inject_false_loops,
            seed=seed,
        ),
        validation=ValidationConfig(
            validator=validator,
            model=validator_model(validator, model),
            loop_threshold=loop_threshold or None,
            loop_precision=loop_precision or None,
            second_look=second_look,
        ),
        consistency=ConsistencyConfig(enabled=consistency is ConsistencyChoice.pcm),
        graph=GraphConfig(robust=robust.value),
        maps=MapConfig(resolution=resolution),
    )
    run_slam_command(
        log,
        read,
        config,
        reference=reference,
        relations=relations,
        join=JoinOptions(time_tolerance, time_offset),
        outputs=SlamOutputs(json_out, loops_out, loops_injected, files),
        voice=Voice(typer.echo, lambda line: typer.echo(line, err=True)),
    )
