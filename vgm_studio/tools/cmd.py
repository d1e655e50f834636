"""The ``vgm-studio`` command line: each command parses, calls one function, prints.

The work is done in ``vgm_studio.services`` (and ``studio.serve``, ``trainer.process``); options
shared between commands are declared once in ``tools/options.py``. Each command imports its
service when it runs, so ``--help`` and a quick ``info`` do not wait for torch to load.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from vgm_studio.datasets import ReadOptions
from vgm_studio.errors import exit_on_error
from vgm_studio.processes import keep_for_good
from vgm_studio.tools import (
    audit_cmd,
    compare_cmd,
    fleet_cmd,
    model_cmds,
    slam_cmd,
    studio_cmds,
    trainer_cmds,
)
from vgm_studio.tools.options import (
    LogArg,
    MaxLoopsOpt,
    TimeToleranceOpt,
    non_negative,
    number,
    png_file,
    positive,
    with_read_options,
    writable_file,
    writable_folder,
)

PROG = "vgm-studio"

app = typer.Typer(
    name=PROG,
    help="Label, validate and debug 2D LiDAR scan-matching edges with Validation Grid Maps.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _warn(line: str) -> None:
    typer.echo(line, err=True)


def _version(value: bool) -> None:
    if value:
        from vgm_studio import __version__

        typer.echo(f"{PROG} {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option(
            "--version", help="Print the version and exit.", is_eager=True, callback=_version
        ),
    ] = False,
) -> None:
    """Label, validate and debug 2D LiDAR scan-matching edges with Validation Grid Maps."""


@app.command()
@with_read_options
def info(
    log: Annotated[
        Path,
        typer.Argument(
            metavar="LOG",
            help="CARMEN log, ROS 1 .bag, ROS 2 bag folder, or Freiburg relations file.",
        ),
    ],
    read: ReadOptions,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    check: Annotated[
        bool,
        typer.Option(
            "--check", help="Only check that scan matches agree with odometry (the laser's mount)."
        ),
    ] = False,
) -> None:
    """Print what a log holds: scans, beams, field of view, duration, poses, distance."""
    from vgm_studio.services import info as service

    describe = service.check if check else service.describe
    typer.echo(describe(log, read, as_json, warn=_warn))


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
            callback=number(0, 360, lo_open=True),
        ),
    ] = 180.0,
    range_noise: Annotated[float, non_negative("Range noise σ, metres (≥ 0).")] = 0.01,
    max_range: Annotated[float, positive("Sensor maximum range, metres (> 0).")] = 30.0,
    people: Annotated[int, typer.Option(help="Moving people in the world.", min=0)] = 0,
    scan_spacing: Annotated[float, positive("Metres travelled between scans (> 0).")] = 0.1,
    laps: Annotated[
        float | None,
        typer.Option(
            help="Laps of the route (> 0).",
            show_default="the preset's",
            callback=number(0, lo_open=True, optional=True),
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
    writable_folder(out)
    typer.echo(f"wrote {run(config, out)}")


@app.command()
@with_read_options
def candidates(
    log: LogArg,
    out: Annotated[Path, typer.Option(metavar="EDGES.jsonl", help="Edges JSONL file to write.")],
    read: ReadOptions,
    reference: Annotated[
        Path | None,
        typer.Option(
            metavar="REF",
            help="Reference: a corrected log, a log with TRUEPOS, or a Freiburg relations file.",
            show_default="the log's own poses",
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed for loop sampling and guess noise.", min=0)] = 0,
    max_loops: MaxLoopsOpt = 2000,
    min_gap: Annotated[
        int, typer.Option(help="Loop pairs at least this many scans apart.", min=0)
    ] = 50,
    max_distance: Annotated[float, positive("Loop pairs within this many metres (> 0).")] = 3.0,
    max_angle: Annotated[
        float,
        typer.Option(
            help="Loop pairs within this many degrees, in (0, 180].",
            callback=number(0, 180, lo_open=True),
        ),
    ] = 45.0,
    noise_xy: Annotated[float, non_negative("Guess noise σ in x and y, metres (≥ 0).")] = 0.3,
    noise_theta: Annotated[float, non_negative("Guess noise σ in θ, degrees (≥ 0).")] = 5.0,
    keyframe_distance: Annotated[
        float, non_negative("Keyframe every this many metres (0: every scan).")
    ] = 0.0,
    keyframe_angle: Annotated[float, non_negative("…or this many degrees (0: off).")] = 0.0,
    sequential: Annotated[bool, typer.Option(help="Make sequential edges.")] = True,
    loops: Annotated[bool, typer.Option(help="Make loop edges.")] = True,
    success_xy: Annotated[float, positive("Success: |e_xy| ≤ this (m)…")] = 0.10,
    success_theta: Annotated[float, positive("…and |e_θ| ≤ this (deg).")] = 2.0,
    failure_xy: Annotated[float, positive("Failure: |e_xy| ≥ this (m, > success)…")] = 0.30,
    failure_theta: Annotated[float, positive("…or |e_θ| ≥ this (deg, > success).")] = 5.0,
    check_reference: Annotated[
        bool,
        typer.Option(
            help="Call a failure ambiguous when the scans contradict the reference: matched "
            "from the reference they come to rest on the estimate, agreeing better there."
        ),
    ] = True,
    time_tolerance: TimeToleranceOpt = 0.05,
    time_offset: Annotated[
        float,
        typer.Option(
            help="Seconds added to a reference log's timestamps before the join "
            "(a GMapping log counts from the start of the run).",
            callback=number(),
        ),
    ] = 0.0,
) -> None:
    """Match candidate edges of a log and label them against a reference; write JSONL."""
    from vgm_studio.datasets.source import JoinOptions
    from vgm_studio.matching.candidates import CandidateConfig
    from vgm_studio.matching.reference_labels import LabelThresholds
    from vgm_studio.services.candidates import make_edge_file

    if not sequential and not loops:
        raise typer.BadParameter("--no-sequential and --no-loops leave no edges to make.")
    for name, ok, fail in (("xy", success_xy, failure_xy), ("theta", success_theta, failure_theta)):
        if ok >= fail:
            raise typer.BadParameter(
                f"--success-{name} {ok:g} must be below --failure-{name} {fail:g}."
            )
    writable_file(out)
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
    thresholds = LabelThresholds(
        success_xy, success_theta, failure_xy, failure_theta, check_reference
    )
    join = JoinOptions(time_tolerance, time_offset)
    run = make_edge_file(log, out, read, reference, join, config, thresholds, warn=_warn)
    typer.echo(run.table())


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
    png: Annotated[
        Path, typer.Option(metavar="FILE.png", help="Picture to write.", callback=png_file)
    ],
    guess: Annotated[
        bool,
        typer.Option(help="Place the current scan by the initial guess instead of the estimate."),
    ] = False,
    size: Annotated[int, typer.Option(help="VGM cells per side.", min=8)] = 400,
    resolution: Annotated[float, positive("VGM cell edge, metres (> 0).")] = 0.05,
    sigma: Annotated[float, positive("VGM covariance regulariser, metres (> 0).")] = 0.02,
) -> None:
    """Draw one edge: both scans in two colours over the two VGM channels."""
    from vgm_studio.vgm.picture import draw_edge

    writable_file(png)
    draw_edge(edges_file, edge, png, use_guess=guess, size=size, resolution=resolution, sigma=sigma)
    typer.echo(f"wrote {png}")


app.command("train")(model_cmds.train)
app.command("eval")(model_cmds.evaluate)
app.command("label")(studio_cmds.label)
app.command("demo")(studio_cmds.demo)
app.command("export")(studio_cmds.export)
app.command("import")(studio_cmds.import_)
app.command("agreement")(studio_cmds.agreement)
app.command("slam")(slam_cmd.slam)
app.command("audit")(audit_cmd.audit)
app.command("compare")(compare_cmd.compare)
app.command("fleet")(fleet_cmd.fleet)
app.command("trainer")(trainer_cmds.trainer)
app.command("models")(trainer_cmds.models)


def main(argv: list[str] | None = None) -> None:
    """Runs the CLI and turns every expected error into one line and an exit code."""
    exit_on_error(PROG, lambda: _run(argv))


def run() -> None:
    """The ``vgm-studio`` program: ``main`` on the command line, in a process that then ends."""
    try:
        main()
    finally:
        keep_for_good()


def _run(argv: list[str] | None) -> None:
    command = typer.main.get_command(app)
    try:
        code = command.main(args=argv, prog_name=PROG, standalone_mode=False)
    except typer.Abort:
        raise KeyboardInterrupt from None
    except typer.TyperException as exc:
        _usage_error(exc)
        return
    # Outside standalone mode an exit comes back as its code, not an exception: typer turns
    # Ctrl-C into exit code 130 so, and a run stopped half-way must not end with 0. Every
    # command returns None, so an int here is an exit code.
    if code == 130:
        raise KeyboardInterrupt
    if isinstance(code, int) and not isinstance(code, bool) and code != 0:
        raise SystemExit(code)


def _usage_error(exc: Exception) -> None:
    """A usage error (unknown option or command, bad value) as one line, exit code 2."""
    ctx = getattr(exc, "ctx", None)
    if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
        typer.echo(ctx.get_help(), err=True)
        raise SystemExit(2)
    name = f" {ctx.info_name}" if ctx is not None and ctx.info_name != PROG else ""
    format_message = getattr(exc, "format_message", None)
    message = format_message() if callable(format_message) else str(exc)
    typer.echo(f"{PROG}{name}: error: {message}", err=True)
    raise SystemExit(int(getattr(exc, "exit_code", 2)))


if __name__ == "__main__":
    run()
