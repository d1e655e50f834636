"""The ``vgm-studio`` command line: thin wrappers over the package's stages."""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
from collections import Counter
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer

from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.errors import InputError
from vgm_studio.tools import model_cmds, slam_cmd, studio_cmds, trainer_cmds
from vgm_studio.tools.sources import report_skipped, warn_if_disagreeing

app = typer.Typer(
    name="vgm-studio",
    help="Label, validate and debug 2D LiDAR scan-matching edges with Validation Grid Maps.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


class Poses(str, Enum):
    auto = "auto"
    odometry = "odometry"
    reference = "reference"


class Laser(str, Enum):
    front = "front"
    rear = "rear"


def _number(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    optional: bool = False,
) -> Any:
    """A typer callback: the value must be finite and within [lo, hi] ((lo, hi] when lo_open).

    click's own ranges let ``nan`` and ``inf`` through (nan compares false with every bound),
    and a non-finite threshold quietly turns every comparison downstream into nonsense.
    """

    def check(value: Any) -> Any:
        if value is None and optional:
            return value
        if not math.isfinite(value):
            raise typer.BadParameter(f"{value} is not a finite number.")
        if lo is not None and (value <= lo if lo_open else value < lo):
            sign = ">" if lo_open else "≥"
            raise typer.BadParameter(f"{value:g} is out of range: it must be {sign} {lo:g}.")
        if hi is not None and value > hi:
            raise typer.BadParameter(f"{value:g} is out of range: it must be ≤ {hi:g}.")
        return value

    return check


def _writable_file(path: Path) -> None:
    """Fails now, before minutes of work, if ``path`` cannot be written.

    Raises:
        InputError: ``path`` is a folder, or its folder cannot be made or written.
    """
    if path.is_dir():
        raise InputError(path, "is a folder; give a file name to write")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(path, f"cannot write here ({exc.strerror or exc})") from None


def _writable_folder(path: Path) -> None:
    """Fails now if ``path`` cannot be a folder to write files into.

    Raises:
        InputError: ``path`` is a file, or cannot be made or written.
    """
    if path.exists() and not path.is_dir():
        raise InputError(path, "is a file, not a folder; --out takes a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".vgm-studio.", dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(path, f"cannot write here ({exc.strerror or exc})") from None


LogArg = Annotated[
    Path, typer.Argument(metavar="LOG", help="CARMEN log, ROS 1 .bag or ROS 2 bag folder.")
]
PosesOpt = Annotated[
    Poses,
    typer.Option(
        help="What the scans' pose fields hold (auto: GMapping output → reference, else odometry)."
    ),
]
FovOpt = Annotated[
    float,
    typer.Option(
        "--fov",
        help="FLASER field of view in degrees, in (0, 360].",
        callback=_number(0, 360, lo_open=True),
    ),
]
MaxRangeOpt = Annotated[
    float | None,
    typer.Option(
        help="Readings at or beyond this (m, > 0) are no-returns.",
        show_default="the message's, or 95% of the log's largest reading",
        callback=_number(0, lo_open=True, optional=True),
    ),
]
LaserOpt = Annotated[Laser, typer.Option(help="front: FLASER/ROBOTLASER1; rear: RLASER.")]
SkipOpt = Annotated[bool, typer.Option(help="Skip malformed lines and report how many.")]
ScanTopicOpt = Annotated[str | None, typer.Option(help="ROS bags: LaserScan topic.")]
OdomTopicOpt = Annotated[str | None, typer.Option(help="ROS bags: Odometry topic.")]


def _laser_pose(value: str | None) -> tuple[float, float, float] | None:
    from vgm_studio.datasets.mount import parse_laser_pose

    if value is None:
        return None
    try:
        return parse_laser_pose(value)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


LaserPoseOpt = Annotated[
    str | None,
    typer.Option(
        metavar="X,Y,YAW",
        help="The laser in the robot's base frame: metres ahead, metres left, degrees.",
        show_default="from the bag's /tf_static or /tf, else at the base",
        callback=_laser_pose,
    ),
]
LaserFlippedOpt = Annotated[
    bool, typer.Option(help="The laser is mounted upside down (its scans are mirrored).")
]


def _read_options(
    poses: Poses,
    fov: float,
    max_range: float | None,
    laser: Laser,
    skip_bad_lines: bool,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    laser_pose: Any = None,
    laser_flipped: bool = False,
) -> ReadOptions:
    return ReadOptions(
        poses=poses.value,
        fov_deg=fov,
        max_range=max_range,
        laser=laser.value,
        skip_bad_lines=skip_bad_lines,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        laser_pose=laser_pose,
        laser_flipped=laser_flipped,
    )


@app.command()
def info(
    log: Annotated[
        Path,
        typer.Argument(
            metavar="LOG",
            help="CARMEN log, ROS 1 .bag, ROS 2 bag folder, or Freiburg relations file.",
        ),
    ],
    poses: PosesOpt = Poses.auto,
    fov: FovOpt = 180.0,
    max_range: MaxRangeOpt = None,
    laser: LaserOpt = Laser.front,
    skip_bad_lines: SkipOpt = False,
    scan_topic: ScanTopicOpt = None,
    odom_topic: OdomTopicOpt = None,
    laser_pose: LaserPoseOpt = None,
    laser_flipped: LaserFlippedOpt = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    check: Annotated[
        bool,
        typer.Option(
            "--check",
            help="Only check that scan matches agree with odometry (the laser's mount).",
        ),
    ] = False,
) -> None:
    """Print what a log holds: scans, beams, field of view, duration, poses, distance."""
    from vgm_studio.datasets.relations import looks_like_relations, read_relations
    from vgm_studio.tools.info import format_summary, summarize

    if log.is_file() and looks_like_relations(log):
        rel = read_relations(log)
        stamps = {r.t_a for r in rel} | {r.t_b for r in rel}
        if as_json:
            summary = {
                "path": str(log),
                "format": "relations",
                "relations": len(rel),
                "timestamps": len(stamps),
            }
            typer.echo(json.dumps(summary, indent=2))
        else:
            typer.echo(
                f"{log}: Freiburg relations file, {len(rel)} relations "
                f"between {len(stamps)} scan timestamps"
            )
        return
    options = _read_options(
        poses,
        fov,
        max_range,
        laser,
        skip_bad_lines,
        scan_topic,
        odom_topic,
        laser_pose,
        laser_flipped,
    )
    scan_log = open_log(log, options)
    if check:
        from vgm_studio.tools.info import check_mount

        check_mount(scan_log, as_json)
        return
    summary = summarize(scan_log)
    typer.echo(json.dumps(summary, indent=2) if as_json else format_summary(summary))
    report_skipped(scan_log)


def _preset(value: Any) -> Any:
    from vgm_studio.simulation.presets import preset_names

    if value not in preset_names():
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(preset_names())}.")
    return value


@app.command()
def simulate(
    out: Annotated[Path, typer.Option(help="Folder to write the log into.")],
    seed: Annotated[int, typer.Option(help="Random seed; same seed, same bytes.", min=0)] = 0,
    preset: Annotated[
        str,
        typer.Option(
            help="World: corridor, l-junction, t-junction, loop, repetitive, office, demo.",
            callback=_preset,
        ),
    ] = "office",
    beams: Annotated[int, typer.Option(help="Beams per scan.", min=2)] = 361,
    fov: Annotated[
        float,
        typer.Option(
            "--fov",
            help="Field of view, degrees, in (0, 360].",
            callback=_number(0, 360, lo_open=True),
        ),
    ] = 180.0,
    range_noise: Annotated[
        float, typer.Option(help="Range noise σ, metres (≥ 0).", callback=_number(0))
    ] = 0.01,
    max_range: Annotated[
        float,
        typer.Option(help="Sensor maximum range, metres (> 0).", callback=_number(0, lo_open=True)),
    ] = 30.0,
    people: Annotated[int, typer.Option(help="Moving people in the world.", min=0)] = 0,
    scan_spacing: Annotated[
        float,
        typer.Option(
            help="Metres travelled between scans (> 0).", callback=_number(0, lo_open=True)
        ),
    ] = 0.1,
    laps: Annotated[
        float | None,
        typer.Option(
            help="Laps of the route (> 0).",
            show_default="the preset's",
            callback=_number(0, lo_open=True, optional=True),
        ),
    ] = None,
) -> None:
    """Write a simulated CARMEN log (TRUEPOS ground truth, noisy odometry) by ray casting."""
    from vgm_studio.simulation.simulate import SimConfig
    from vgm_studio.simulation.simulate import simulate as run

    config = SimConfig(
        preset=preset,
        seed=seed,
        num_beams=beams,
        fov_deg=fov,
        range_noise=range_noise,
        max_range=max_range,
        people=people,
        scan_spacing=scan_spacing,
        laps=laps,
    )
    _writable_folder(out)
    path = run(config, out)
    typer.echo(f"wrote {path}")


def _positive(what: str) -> Any:
    return typer.Option(help=what, callback=_number(0, lo_open=True))


def _non_negative(what: str) -> Any:
    return typer.Option(help=what, callback=_number(0))


@app.command()
def candidates(
    log: LogArg,
    out: Annotated[Path, typer.Option(metavar="EDGES.jsonl", help="Edges JSONL file to write.")],
    reference: Annotated[
        Path | None,
        typer.Option(
            metavar="REF",
            help="Reference: a corrected log, a log with TRUEPOS, or a Freiburg relations file.",
            show_default="the log's own poses",
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed for loop sampling and guess noise.", min=0)] = 0,
    max_loops: Annotated[int, typer.Option("--max", help="Loop candidates at most.", min=1)] = 2000,
    min_gap: Annotated[
        int, typer.Option(help="Loop pairs at least this many scans apart.", min=0)
    ] = 50,
    max_distance: Annotated[float, _positive("Loop pairs within this many metres (> 0).")] = 3.0,
    max_angle: Annotated[
        float,
        typer.Option(
            help="Loop pairs within this many degrees, in (0, 180].",
            callback=_number(0, 180, lo_open=True),
        ),
    ] = 45.0,
    noise_xy: Annotated[float, _non_negative("Guess noise σ in x and y, metres (≥ 0).")] = 0.3,
    noise_theta: Annotated[float, _non_negative("Guess noise σ in θ, degrees (≥ 0).")] = 5.0,
    keyframe_distance: Annotated[
        float, _non_negative("Keyframe every this many metres (0: every scan).")
    ] = 0.0,
    keyframe_angle: Annotated[float, _non_negative("…or this many degrees (0: off).")] = 0.0,
    sequential: Annotated[bool, typer.Option(help="Make sequential edges.")] = True,
    loops: Annotated[bool, typer.Option(help="Make loop edges.")] = True,
    success_xy: Annotated[float, _positive("Success: |e_xy| ≤ this (m)…")] = 0.10,
    success_theta: Annotated[float, _positive("…and |e_θ| ≤ this (deg).")] = 2.0,
    failure_xy: Annotated[float, _positive("Failure: |e_xy| ≥ this (m, > success)…")] = 0.30,
    failure_theta: Annotated[float, _positive("…or |e_θ| ≥ this (deg, > success).")] = 5.0,
    time_tolerance: Annotated[
        float,
        typer.Option(
            help="Reference timestamps match within this many seconds, in (0, 10].",
            callback=_number(0, 10, lo_open=True),
        ),
    ] = 0.05,
    time_offset: Annotated[
        float,
        typer.Option(
            help="Seconds added to a reference log's timestamps before the join "
            "(a GMapping log counts from the start of the run).",
            callback=_number(),
        ),
    ] = 0.0,
    poses: PosesOpt = Poses.auto,
    fov: FovOpt = 180.0,
    max_range: MaxRangeOpt = None,
    laser: LaserOpt = Laser.front,
    skip_bad_lines: SkipOpt = False,
    scan_topic: ScanTopicOpt = None,
    odom_topic: OdomTopicOpt = None,
    laser_pose: LaserPoseOpt = None,
    laser_flipped: LaserFlippedOpt = False,
) -> None:
    """Match candidate edges of a log and label them against a reference; write JSONL."""
    from vgm_studio.matching.candidates import CandidateConfig, make_candidates
    from vgm_studio.matching.edges import write_edges
    from vgm_studio.matching.labels import LabelThresholds
    from vgm_studio.matching.matcher import ScanMatcher
    from vgm_studio.tools.sources import read_source

    if not sequential and not loops:
        raise typer.BadParameter("--no-sequential and --no-loops leave no edges to make.")
    if success_xy >= failure_xy:
        raise typer.BadParameter(
            f"--success-xy {success_xy:g} must be below --failure-xy {failure_xy:g}."
        )
    if success_theta >= failure_theta:
        raise typer.BadParameter(
            f"--success-theta {success_theta:g} must be below --failure-theta {failure_theta:g}."
        )
    _writable_file(out)
    options = _read_options(
        poses,
        fov,
        max_range,
        laser,
        skip_bad_lines,
        scan_topic,
        odom_topic,
        laser_pose,
        laser_flipped,
    )
    source = read_source(
        log,
        options,
        reference,
        time_tolerance=time_tolerance,
        time_offset=time_offset,
        max_loops=max_loops if loops else None,
    )
    config = CandidateConfig(
        sequential=sequential,
        loops=loops,
        keyframe_distance=keyframe_distance,
        keyframe_angle_deg=keyframe_angle,
        min_gap=min_gap,
        max_distance=max_distance,
        max_angle_deg=max_angle,
        max_loops=max_loops,
        seed=seed,
        noise_xy=noise_xy,
        noise_theta_deg=noise_theta,
    )
    thresholds = LabelThresholds(success_xy, success_theta, failure_xy, failure_theta)
    start = time.perf_counter()
    edges = make_candidates(
        source.log, ScanMatcher(), config, thresholds, source.relations, source.params
    )
    seconds = time.perf_counter() - start
    try:
        write_edges(out, edges)
    except OSError as exc:
        raise InputError(out, f"cannot write ({exc.strerror or exc})") from None
    _print_edge_summary(edges, seconds, out)
    warn_if_disagreeing(source.log, edges)


def _print_edge_summary(edges: list[Any], seconds: float, out: Path) -> None:
    counts = Counter((e.kind, e.label or "unlabelled") for e in edges)
    typer.echo(
        f"wrote {len(edges)} edges to {out} in {seconds:.1f} s "
        f"({len(edges) / max(seconds, 1e-9):.0f} edges/s)"
    )
    labels = ("success", "failure", "ambiguous", "unlabelled")
    typer.echo(f"{'kind':<12}" + "".join(f"{lab:>12}" for lab in labels))
    for kind in ("sequential", "loop"):
        if any(k == kind for k, _ in counts):
            typer.echo(f"{kind:<12}" + "".join(f"{counts[(kind, lab)]:>12}" for lab in labels))


def _png(value: Any) -> Any:
    if value.is_dir():
        raise typer.BadParameter(f"{value} is a folder; give a .png file name.")
    if value.suffix.lower() != ".png":
        raise typer.BadParameter(f"{value} must end in .png (pictures are written as PNG).")
    return value


@app.command()
def vgm(
    edges_file: Annotated[Path, typer.Argument(metavar="EDGES.jsonl", help="Edges file.")],
    edge: Annotated[
        str,
        typer.Option(
            metavar="ID",
            help="edge_id (or a unique prefix) to draw; the first field of each line.",
        ),
    ],
    png: Annotated[Path, typer.Option(metavar="FILE.png", help="Picture to write.", callback=_png)],
    guess: Annotated[
        bool,
        typer.Option(help="Place the current scan by the initial guess instead of the estimate."),
    ] = False,
    size: Annotated[int, typer.Option(help="VGM cells per side.", min=8)] = 400,
    resolution: Annotated[float, _positive("VGM cell edge, metres (> 0).")] = 0.05,
    sigma: Annotated[float, _positive("VGM covariance regulariser, metres (> 0).")] = 0.02,
) -> None:
    """Draw one edge: both scans in two colours over the two VGM channels."""
    from vgm_studio.matching.edges import read_edges
    from vgm_studio.vgm.picture import edge_picture

    edges = read_edges(edges_file)
    hits = [e for e in edges if e.edge_id.startswith(edge)]
    if len(hits) != 1:
        what = "no edge" if not hits else f"{len(hits)} edges"
        raise InputError(edges_file, f"{what} with id {edge!r}")
    _writable_file(png)
    edge_picture(
        hits[0],
        png,
        use_guess=guess,
        size=size,
        resolution=resolution,
        sigma=sigma,
        search_dirs=(edges_file.parent,),
    )
    typer.echo(f"wrote {png}")


app.command("train")(model_cmds.train)
app.command("eval")(model_cmds.evaluate)
app.command("label")(studio_cmds.label)
app.command("demo")(studio_cmds.demo)
app.command("export")(studio_cmds.export)
app.command("import")(studio_cmds.import_)
app.command("slam")(slam_cmd.slam)
app.command("trainer")(trainer_cmds.trainer)
app.command("models")(trainer_cmds.models)


def main(argv: list[str] | None = None) -> None:
    """Entry point: runs the CLI and turns every expected error into one line and an exit code."""
    command = typer.main.get_command(app)
    try:
        command.main(args=argv, prog_name="vgm-studio", standalone_mode=False)
    except InputError as exc:
        typer.echo(f"vgm-studio: error: {exc}", err=True)
        sys.exit(1)
    except (typer.Abort, KeyboardInterrupt):
        typer.echo("vgm-studio: interrupted", err=True)
        sys.exit(130)
    except typer.TyperException as exc:
        _usage_error(exc)
    except BrokenPipeError:
        sys.exit(0)


def _usage_error(exc: Exception) -> None:
    """A usage error (unknown option or command, bad value) as one line, exit code 2."""
    ctx = getattr(exc, "ctx", None)
    if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
        typer.echo(ctx.get_help(), err=True)
        sys.exit(2)
    name = f" {ctx.info_name}" if ctx is not None and ctx.info_name != "vgm-studio" else ""
    format_message = getattr(exc, "format_message", None)
    message = format_message() if callable(format_message) else str(exc)
    typer.echo(f"vgm-studio{name}: error: {message}", err=True)
    sys.exit(int(getattr(exc, "exit_code", 2)))


if __name__ == "__main__":
    main()
