"""``vgm-studio compare``: two runs of one log, what changed, and rules a CI job fails on."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from vgm_studio.errors import InputError
from vgm_studio.tools.options import png_file, positive

_RULES_HELP = (
    "Rules, NAME=LIMIT joined by commas; exit 1 when one fails. error-increase and "
    "rot-error-increase (the after error) take a share (10%), an amount (0.005 m / °) or "
    "'noise'; new-false-loops, lost-right-loops, newly-kept, newly-dropped, flipped and "
    "moved-keyframes take the most allowed."
)


def _noise(value: str) -> tuple[float, float]:
    """``FLOOR_M,SHARE%`` (``0.002,10%``) → (floor, share)."""
    floor, _, share = value.partition(",")
    try:
        out = float(floor), float(share.strip().rstrip("%")) / 100 if share else 0.10
    except ValueError:
        raise typer.BadParameter(f"{value!r} is not FLOOR_M,SHARE% (e.g. 0.002,10%).") from None
    if min(out) < 0:
        raise typer.BadParameter(f"{value!r}: the floor and the share must be at least 0.")
    return out


def compare(
    base: Annotated[
        Path, typer.Argument(metavar="BASE", help="The base run's --json (slam or audit).")
    ],
    new: Annotated[Path, typer.Argument(metavar="NEW", help="The new run's --json, same log.")],
    fail_on: Annotated[str, typer.Option("--fail-on", metavar="RULES", help=_RULES_HELP)] = "",
    noise: Annotated[
        str,
        typer.Option(
            metavar="FLOOR_M,SHARE%",
            help="Run-to-run noise of the relation errors: a change within FLOOR_M + SHARE of "
            "the base is noise (rotation: 0.05° + SHARE). The default is the nudged spread "
            "of BENCHMARKS.md (bench_slam.py --nudge): ≤ 1 mm on most buildings, up to a "
            "third of the error on the fickle ones.",
        ),
    ] = "0.002,10%",
    scan_tolerance: Annotated[
        int,
        typer.Option(
            help="Loops whose ends lie within this many scans are the same loop (two runs "
            "may pick other keyframes).",
            min=0,
        ),
    ] = 5,
    moved: Annotated[
        float,
        positive(
            "A keyframe (at a scan both runs made one of) moved when its after pose differs "
            "by more, metres (> 0), or turned by more than 2°."
        ),
    ] = 0.10,
    png: Annotated[
        Path | None,
        typer.Option(
            metavar="OUT.png",
            help="The two after maps over each other (drawn from the log the runs name).",
            callback=lambda v: v if v is None else png_file(v),
        ),
    ] = None,
    markdown: Annotated[
        Path | None,
        typer.Option(metavar="OUT.md", help="The comparison as a CI summary page."),
    ] = None,
    studio_url: Annotated[
        str | None,
        typer.Option(
            metavar="URL",
            help="The studio's address (http://HOST:PORT): each listed loop links to "
            "URL/?edge=EDGE_ID.",
        ),
    ] = None,
    log: Annotated[
        Path | None,
        typer.Option(
            metavar="LOG",
            help="The runs' log for --png, where it is not at the path their JSON names "
            "(checked by content hash).",
        ),
    ] = None,
    resolution: Annotated[float, positive("Map cell edge for --png, metres (> 0).")] = 0.05,
) -> None:
    """Compare two runs of one log: relation errors, loops by scan pair, moved keyframes.

    Exit status: 0 when every --fail-on rule holds, 1 when one fails, 2 on bad input.
    """
    from vgm_studio.compare import CompareConfig, Noise
    from vgm_studio.services import Voice
    from vgm_studio.services.compare import CompareOutputs, run_compare

    floor, share = _noise(noise)
    config = CompareConfig(
        noise=Noise(floor_m=floor, share=share), scan_tolerance=scan_tolerance, moved_m=moved
    )
    outputs = CompareOutputs(png, markdown, studio_url, log, resolution)
    voice = Voice(say=typer.echo, warn=lambda line: typer.echo(line, err=True))
    try:
        result = run_compare(base, new, config, fail_on, outputs, voice)
    except InputError as exc:
        # Bad input exits 2: a CI job reads 1 as "the new run is worse".
        raise InputError(exc.path, exc.message, exc.line, exit_code=2) from None
    for o in result.failed:
        typer.echo(f"vgm-studio compare: failed: {o.rule.text}: {o.detail}", err=True)
    if result.failed:
        raise typer.Exit(1)
