"""``vgm-studio slam``: a whole graph-SLAM run with validated edges, maps, metrics, a recording.

Registered in ``tools/cmd.py``; the shared option helpers live there and are imported when
the command runs (``cmd`` imports this module, so a module-level import would be a cycle).
"""

from __future__ import annotations

import json
import time
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer

from vgm_studio.errors import InputError

BUNDLED_MODEL = Path(__file__).resolve().parents[2] / "assets" / "models" / "vgmnet-default.pt"


class ValidatorChoice(str, Enum):
    none = "none"
    vgmnet = "vgmnet"
    rgb_baseline = "rgb-baseline"
    score = "score"
    reference = "reference"


class RobustChoice(str, Enum):
    none = "none"
    huber = "huber"
    gnc = "gnc"


class PosesChoice(str, Enum):
    auto = "auto"
    odometry = "odometry"
    reference = "reference"


class LaserChoice(str, Enum):
    front = "front"
    rear = "rear"


def _checked(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    optional: bool = False,
) -> Any:
    """``cmd._number``'s finite-and-in-range check, looked up when the value arrives."""

    def check(value: Any) -> Any:
        from vgm_studio.tools.cmd import _number

        return _number(lo, hi, lo_open=lo_open, optional=optional)(value)

    return check


def _laser_pose(value: str | None) -> Any:
    from vgm_studio.tools.cmd import _laser_pose as parse

    return parse(value)


def _positive(what: str) -> Any:
    return typer.Option(help=what, callback=_checked(0, lo_open=True))


def slam(
    log: Annotated[
        Path, typer.Argument(metavar="LOG", help="CARMEN log, ROS 1 .bag or ROS 2 bag folder.")
    ],
    validator: Annotated[
        ValidatorChoice,
        typer.Option(
            help="Which edges enter the graph: none (all), a model (vgmnet, rgb-baseline, "
            "score; see --model) or reference (edges that land on the reference pose)."
        ),
    ] = ValidatorChoice.vgmnet,
    model: Annotated[
        Path | None,
        typer.Option(
            metavar="MODEL.pt",
            help="Checkpoint for the model validators.",
            show_default="assets/models/vgmnet-default.pt for vgmnet",
        ),
    ] = None,
    loop_threshold: Annotated[
        float,
        typer.Option(
            help="p(success) a loop edge needs, in [0, 1]; never below the checkpoint's "
            "threshold (0: the checkpoint's alone).",
            callback=_checked(0, 1),
        ),
    ] = 0.8,
    robust: Annotated[
        RobustChoice,
        typer.Option(help="Back-end outlier handling: none, huber kernels, or gnc (TLS)."),
    ] = RobustChoice.none,
    reference: Annotated[
        Path | None,
        typer.Option(
            metavar="REF",
            help="Reference poses for --validator reference: a corrected log or a log with "
            "TRUEPOS.",
            show_default="the log's own reference poses",
        ),
    ] = None,
    time_offset: Annotated[
        float,
        typer.Option(
            help="Seconds added to the reference log's timestamps before the join.",
            callback=_checked(),
        ),
    ] = 0.0,
    time_tolerance: Annotated[
        float,
        typer.Option(
            help="Reference timestamps match within this many seconds, in (0, 10].",
            callback=_checked(0, 10, lo_open=True),
        ),
    ] = 0.05,
    relations: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="Freiburg relations file: report the relation errors (Kümmerle et al. 2009).",
        ),
    ] = None,
    json_out: Annotated[
        Path | None,
        typer.Option("--json", metavar="OUT", help="Write the run's figures as JSON."),
    ] = None,
    map_png: Annotated[
        Path | None,
        typer.Option(
            metavar="DIR", help="Write odometry, before and after maps (and all three) as PNG."
        ),
    ] = None,
    record: Annotated[
        Path | None,
        typer.Option(metavar="OUT.rrd", help="Write a rerun recording (no viewer needed)."),
    ] = None,
    spawn: Annotated[bool, typer.Option(help="Open the rerun viewer on the run.")] = False,
    keyframe_distance: Annotated[float, _positive("Keyframe every this many metres (> 0).")] = 0.5,
    keyframe_angle: Annotated[float, _positive("…or this many degrees (> 0).")] = 20.0,
    loop_radius: Annotated[
        float, _positive("Loop candidates within this many metres of the estimate (> 0).")
    ] = 3.0,
    loop_min_gap: Annotated[
        int, typer.Option(help="Loop candidates at least this many keyframes back.", min=1)
    ] = 20,
    loops_per_keyframe: Annotated[
        int, typer.Option(help="Nearest loop candidates matched per keyframe.", min=0)
    ] = 2,
    resolution: Annotated[float, _positive("Map cell edge, metres (> 0).")] = 0.05,
    inject_false_loops: Annotated[
        int,
        typer.Option(help="Inject this many false loop closures (robustness tests).", min=0),
    ] = 0,
    seed: Annotated[int, typer.Option(help="Seed for the injected loops.", min=0)] = 0,
    poses: Annotated[
        PosesChoice,
        typer.Option(help="What the scans' pose fields hold (auto: GMapping output → reference)."),
    ] = PosesChoice.auto,
    fov: Annotated[
        float,
        typer.Option(
            "--fov",
            help="FLASER field of view in degrees, in (0, 360].",
            callback=_checked(0, 360, lo_open=True),
        ),
    ] = 180.0,
    max_range: Annotated[
        float | None,
        typer.Option(
            help="Readings at or beyond this (m, > 0) are no-returns.",
            show_default="the message's, or 95% of the log's largest reading",
            callback=_checked(0, lo_open=True, optional=True),
        ),
    ] = None,
    laser: Annotated[
        LaserChoice, typer.Option(help="front: FLASER/ROBOTLASER1; rear: RLASER.")
    ] = LaserChoice.front,
    skip_bad_lines: Annotated[
        bool, typer.Option(help="Skip malformed lines and report how many.")
    ] = False,
    scan_topic: Annotated[str | None, typer.Option(help="ROS bags: LaserScan topic.")] = None,
    odom_topic: Annotated[str | None, typer.Option(help="ROS bags: Odometry topic.")] = None,
    laser_pose: Annotated[
        str | None,
        typer.Option(
            metavar="X,Y,YAW",
            help="The laser in the robot's base frame: metres ahead, metres left, degrees.",
            show_default="from the bag's /tf_static or /tf, else at the base",
            callback=_laser_pose,
        ),
    ] = None,
    laser_flipped: Annotated[
        bool, typer.Option(help="The laser is mounted upside down (its scans are mirrored).")
    ] = False,
) -> None:
    """Graph SLAM with validated edges: odometry, loops, gtsam, maps, metrics, a recording."""
    from vgm_studio.datasets import ReadOptions, open_log
    from vgm_studio.datasets.reference import with_reference
    from vgm_studio.datasets.relations import looks_like_relations, match_relations, read_relations
    from vgm_studio.graph.config import GraphConfig
    from vgm_studio.maps.config import MapConfig
    from vgm_studio.slam.config import FrontEndConfig, SlamConfig, ValidationConfig
    from vgm_studio.tools.cmd import _writable_file, _writable_folder
    from vgm_studio.tools.sources import mount_options, report_skipped

    start = time.perf_counter()
    if log.is_file() and looks_like_relations(log):
        raise InputError(log, "this is a Freiburg relations file; pass it as --relations")
    if validator.value in ("vgmnet", "rgb-baseline", "score") and model is None:
        if validator is not ValidatorChoice.vgmnet:
            raise InputError(
                None,
                f"--validator {validator.value} needs --model, a checkpoint made by "
                f"vgm-studio train --model {validator.value}",
            )
        model = BUNDLED_MODEL
    for out in (json_out, record):
        if out is not None:
            _writable_file(out)
    if map_png is not None:
        _writable_folder(map_png)
    options = ReadOptions(
        poses=poses.value,
        fov_deg=fov,
        max_range=max_range,
        laser=laser.value,
        skip_bad_lines=skip_bad_lines,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        laser_pose=laser_pose,  # type: ignore[arg-type]  # parsed by _laser_pose
        laser_flipped=laser_flipped,
    )
    scan_log = open_log(log, options)
    report_skipped(scan_log)
    matched = None
    if relations is not None:
        if relations.is_file() and not looks_like_relations(relations):
            raise InputError(
                relations,
                "is not a Freiburg relations file (t1 t2 x y z roll pitch yaw on each line)",
            )
        matched, missed = match_relations(read_relations(relations), scan_log.timestamps)
        if not matched:
            raise InputError(relations, f"no relation matches scans of {log} by timestamp")
        if missed:
            typer.echo(f"{relations}: {missed} relation(s) match no scan pair", err=True)
    if reference is not None:
        if looks_like_relations(reference):
            raise InputError(
                reference,
                "relations give no pose per scan; --reference takes a corrected log or a "
                "log with TRUEPOS (relations go to --relations)",
            )
        ref_log = open_log(reference, mount_options(options))
        scan_log = with_reference(scan_log, ref_log, time_tolerance, time_offset)
    config = SlamConfig(
        front_end=FrontEndConfig(
            keyframe_distance=keyframe_distance,
            keyframe_angle_deg=keyframe_angle,
            loop_radius=loop_radius,
            loop_min_gap=loop_min_gap,
            loops_per_keyframe=loops_per_keyframe,
            false_loops=inject_false_loops,
            seed=seed,
        ),
        validation=ValidationConfig(
            validator=validator.value,
            model=model,
            loop_threshold=loop_threshold or None,
        ),
        graph=GraphConfig(robust=robust.value),
        maps=MapConfig(resolution=resolution),
    )
    _run(scan_log, config, matched, json_out, map_png, record, spawn, start)


def _run(
    scan_log: Any,
    config: Any,
    matched: Any,
    json_out: Path | None,
    map_png: Path | None,
    record: Path | None,
    spawn: bool,
    start: float,
) -> None:
    from dataclasses import asdict

    from vgm_studio.maps.png import write_maps
    from vgm_studio.slam.pipeline import run_slam
    from vgm_studio.slam.report import edge_line, errors_of, run_maps, summary, table

    result = run_slam(scan_log, config)
    typer.echo(edge_line(result))
    _say_what_is_missing(scan_log, result)
    _check_agreement(scan_log, result)
    errors = errors_of(result, matched) if matched is not None else None
    if errors is not None:
        typer.echo(table(errors))
    maps = None
    if map_png is not None or record is not None or spawn:
        t = time.perf_counter()
        maps = run_maps(scan_log, result, config.maps)
        result.seconds["maps"] = time.perf_counter() - t
    if map_png is not None and maps is not None:
        for path in write_maps(map_png, maps):
            typer.echo(f"wrote {path}")
    if record is not None or spawn:
        from vgm_studio.recording import write_recording

        t = time.perf_counter()
        write_recording(scan_log, result, maps or {}, errors, record, spawn)
        result.seconds["recording"] = time.perf_counter() - t
        if record is not None:
            typer.echo(f"wrote {record}")
    seconds = time.perf_counter() - start
    if json_out is not None:
        settings = json.loads(json.dumps(asdict(config), default=str))
        doc = summary(result, errors, settings, seconds)
        try:
            json_out.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        except OSError as exc:
            raise InputError(json_out, f"cannot write ({exc.strerror or exc})") from None
        typer.echo(f"wrote {json_out}")
    typer.echo(f"done in {seconds:.1f} s")


def _check_agreement(scan_log: Any, result: Any) -> None:
    """Warns when the sequential matches disagree with the log's wheel odometry."""
    from vgm_studio.matching.agreement import check_agreement, motions_of
    from vgm_studio.tools.sources import report_agreement

    seq = [e for e in result.edges if e.kind == "sequential"]
    keys = result.keyframes
    motions = motions_of(
        [(int(keys[e.a]), int(keys[e.b])) for e in seq],
        [e.estimate for e in seq],
        [e.match.covariance for e in seq],
    )
    report_agreement(scan_log, check_agreement(scan_log, motions))


def _say_what_is_missing(scan_log: Any, result: Any) -> None:
    """A short or still log runs to the end; these lines say why its outputs are thin."""
    if not any(s.odometry is not None for s in scan_log.scans):
        typer.echo(
            f"{scan_log.path}: no odometry in this log; kiss-icp alone gives the motion", err=True
        )
    if len(result.keyframes) < 2:
        typer.echo(
            f"{scan_log.path}: one keyframe (the robot never moved a keyframe's distance or "
            "angle): no edges and no loops; the maps and recording hold that one scan",
            err=True,
        )
