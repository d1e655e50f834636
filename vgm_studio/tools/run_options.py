"""Options ``slam`` and ``audit`` share: the validator, the reference, and the files a run
writes. Declared once, so each means the same in both commands."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from vgm_studio.slam.config import VALIDATORS
from vgm_studio.tools.options import number, one_of, positive, writable_file, writable_folder

if TYPE_CHECKING:
    from vgm_studio.services.outputs import RunFiles

ModelOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="MODEL.pt",
        help="Checkpoint for the model validators.",
        show_default="assets/models/vgmnet-default.pt for vgmnet",
    ),
]
LoopThresholdOpt = Annotated[
    float,
    typer.Option(
        help="p(success) a loop edge needs, in [0, 1]; never below the checkpoint's "
        "threshold (0: the checkpoint's alone).",
        callback=number(0, 1),
    ),
]
ReferenceOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="REF",
        help="Reference poses (a corrected log or a log with TRUEPOS): the run is scored "
        "against relations drawn from them (unless --relations), and --validator "
        "reference uses them.",
        show_default="the log's own reference poses",
    ),
]
TimeOffsetOpt = Annotated[
    float,
    typer.Option(
        help="Seconds added to the reference log's timestamps before the join.",
        callback=number(),
    ),
]
RelationsOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="FILE",
        help="Freiburg relations file: report the relation errors (Kümmerle et al. 2009).",
    ),
]
JsonOutOpt = Annotated[
    Path | None,
    typer.Option("--json", metavar="OUT", help="Write the run's figures as JSON."),
]
MapPngOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="DIR",
        help="Write the maps of each trajectory (and all three, and the after map with its "
        "loops) as PNG.",
    ),
]
RosMapOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="DIR",
        help="Write the after map as ROS map_server / Nav2 load it: DIR/map.pgm and DIR/map.yaml.",
    ),
]
TrajectoryOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="OUT.txt",
        help="Write every scan's pose of the after graph as a TUM trajectory "
        "(timestamp x y z qx qy qz qw), as evo and other evaluation tools read it.",
    ),
]
G2oOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="OUT.g2o",
        help="Write the after graph as g2o 2D (VERTEX_SE2 with each keyframe's scan as "
        "ROBOTLASER1, EDGE_SE2, FIX), as g2o, gtsam and other optimisers read it.",
    ),
]
RecordOpt = Annotated[
    Path | None,
    typer.Option(metavar="OUT.rrd", help="Write a rerun recording (no viewer needed)."),
]
SpawnOpt = Annotated[bool, typer.Option(help="Open the rerun viewer on the run.")]
ResolutionOpt = Annotated[float, positive("Map cell edge, metres (> 0).")]
InjectOpt = Annotated[
    int,
    typer.Option(help="Inject this many false loop closures (robustness tests).", min=0),
]
InjectSeedOpt = Annotated[int, typer.Option(help="Seed for the injected loops.", min=0)]


def validator_option(what: str) -> object:
    """The ``--validator`` option, with what it decides in this command."""
    return one_of(VALIDATORS, what)


def run_files(
    maps: Path | None,
    record: Path | None,
    spawn: bool,
    trajectory: Path | None,
    ros_map: Path | None,
    g2o: Path | None,
) -> RunFiles:
    """The files a run writes (``--map-png``, ``--record``, ``--spawn``, ``--trajectory``,
    ``--ros-map``, ``--g2o``), each checked writable now."""
    from vgm_studio.services.outputs import RunFiles  # loads the stages: not for --help

    check_writable([record, trajectory, g2o], {"--map-png": maps, "--ros-map": ros_map})
    return RunFiles(maps, record, spawn, trajectory, ros_map, g2o)


def check_writable(
    files: Sequence[Path | None], folders: dict[str, Path | None] | None = None
) -> None:
    """Fails now, before minutes of work, where an output cannot be written."""
    for path in files:
        if path is not None:
            writable_file(path)
    for flag, folder in (folders or {}).items():
        if folder is not None:
            writable_folder(folder, flag)
