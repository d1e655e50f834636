"""The command line's shared options: value checks, path checks, and option types declared once.

Every command takes its options from here, so an option means the same in every command and is
checked the same way. Read options (how a log is read) are added to a command whole by
``with_read_options``; the command receives them as one ``ReadOptions``.
"""

from __future__ import annotations

import functools
import inspect
import math
import os
import re
import tempfile
import time
from collections.abc import Callable, Sequence
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer

from vgm_studio.atomic import file_in_the_way
from vgm_studio.datasets import ReadOptions
from vgm_studio.datasets.mount import parse_laser_pose
from vgm_studio.errors import InputError


def number(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    optional: bool = False,
) -> Callable[[Any], Any]:
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


def positive(what: str) -> Any:
    """An option whose value must be a finite number > 0."""
    return typer.Option(help=what, callback=number(0, lo_open=True))


def non_negative(what: str) -> Any:
    """An option whose value must be a finite number ≥ 0."""
    return typer.Option(help=what, callback=number(0))


def one_of(names: Sequence[str], what: str) -> Any:
    """An option whose value is one of ``names`` (a registry's list), shown in ``--help``."""

    def check(value: Any) -> Any:
        if value not in names:
            raise typer.BadParameter(f"{value!r} is not one of {', '.join(names)}.")
        return value

    return typer.Option(help=what, metavar="[" + "|".join(names) + "]", callback=check)


def writable_file(path: Path) -> None:
    """Fails now, before minutes of work, if ``path`` cannot be written.

    Raises:
        InputError: ``path`` is a folder, or its folder cannot be made or written.
    """
    if path.is_dir():
        raise InputError(path, "is a folder; give a file name to write")
    _probe(path.parent, f".{path.name}.", path)


def writable_folder(path: Path, option: str = "--out") -> None:
    """Fails now if ``path`` cannot be a folder to write files into.

    Args:
        path: The folder.
        option: The option that named it, for the message.

    Raises:
        InputError: ``path`` is a file, or cannot be made or written.
    """
    if path.exists() and not path.is_dir():
        raise InputError(path, f"is a file, not a folder; {option} takes a folder")
    _probe(path, ".vgm-studio.", path)


def _probe(folder: Path, prefix: str, named: Path) -> None:
    """Makes ``folder`` and writes a file in it, or says (of ``named``) why not."""
    in_the_way = file_in_the_way(folder)
    if in_the_way is not None:
        raise InputError(named, f"cannot write here ({in_the_way} is a file, not a folder)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=prefix, dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(named, f"cannot write here ({exc.strerror or exc})") from None


def png_file(value: Any) -> Any:
    """A typer callback: a picture to write must be a ``.png`` file name."""
    if value.is_dir():
        raise typer.BadParameter(f"{value} is a folder; give a .png file name.")
    if value.suffix.lower() != ".png":
        raise typer.BadParameter(f"{value} must end in .png (pictures are written as PNG).")
    return value


class Poses(str, Enum):
    auto = "auto"
    odometry = "odometry"
    reference = "reference"


class Laser(str, Enum):
    front = "front"
    rear = "rear"


class Device(str, Enum):
    auto = "auto"
    cpu = "cpu"
    cuda = "cuda"


LogArg = Annotated[
    Path, typer.Argument(metavar="LOG", help="CARMEN log, ROS 1 .bag or ROS 2 bag folder.")
]
FovOpt = Annotated[
    float,
    typer.Option(
        "--fov",
        help="FLASER field of view in degrees, in (0, 360].",
        callback=number(0, 360, lo_open=True),
    ),
]
TimeToleranceOpt = Annotated[
    float,
    typer.Option(
        help="Reference timestamps match within this many seconds, in (0, 10].",
        callback=number(0, 10, lo_open=True),
    ),
]
MaxLoopsOpt = Annotated[int, typer.Option("--max", help="Loop candidates at most.", min=1)]
SeedOpt = Annotated[int, typer.Option(help="Random seed.", min=0)]
WorkspaceOpt = Annotated[Path, typer.Option(metavar="DIR", help="Workspace folder (label store).")]
StoreOpt = Annotated[
    str | None,
    typer.Option(
        "--store",
        metavar="URL",
        help="A team label store, postgresql://USER@HOST[:PORT]/DB, in place of --workspace.",
    ),
]
ModelsDirOpt = Annotated[
    Path | None,
    typer.Option(
        metavar="DIR", help="With --store: the folder for model files.", show_default="DB.models"
    ),
]


def store_location(
    workspace: Path | None, store: str | None, models_dir: Path | None, default: Path | None = None
) -> tuple[Path, str | None]:
    """(workspace folder or models folder, team store URL or None) from the store options.

    Raises:
        InputError: Both --workspace and --store, neither (without a default), or --models-dir
            without --store.
    """
    if workspace is not None and store is not None:
        raise InputError(None, "--workspace and --store exclude each other: give one")
    if store is not None:
        name = store.rstrip("/").rsplit("/", 1)[-1] or "vgm"
        return models_dir or Path(f"{name}.models"), store
    if models_dir is not None:
        raise InputError(None, "--models-dir goes with --store (a workspace keeps its models/)")
    if workspace is None and default is None:
        raise InputError(None, "give --workspace DIR or --store URL")
    return workspace or default or Path(), None


DeviceOpt = Annotated[Device, typer.Option(help="auto takes a GPU when there is one.")]
PortOpt = Annotated[int, typer.Option(help="TCP port.", min=1, max=65535)]
HostOpt = Annotated[
    str,
    typer.Option(
        help="Interface to listen on; anything but loopback needs the token in the address."
    ),
]


def _token(value: str | None) -> str | None:
    if value is not None and not re.fullmatch(r"[A-Za-z0-9_-]{8,128}", value):
        raise typer.BadParameter("8 to 128 letters, digits, '-' or '_' (it goes in the URL)")
    return value


TokenOpt = Annotated[
    str | None,
    typer.Option(
        metavar="TOKEN",
        help="Required in the studio's address (http://HOST:PORT/TOKEN).",
        show_default="none on loopback, else one made up and printed",
        callback=_token,
    ),
]
AnnotatorOpt = Annotated[
    str | None, typer.Option(help="Your name on the labels.", show_default="your login")
]
NoTrainerOpt = Annotated[
    bool, typer.Option("--no-trainer", help="Run no background trainer beside the studio.")
]
RetrainOpt = Annotated[
    int, typer.Option(help="The trainer trains after this many new labels.", min=1)
]
MinHeldOutOpt = Annotated[
    int,
    typer.Option(
        min=1, help="Held-out labels of each class a version needs before it is promoted."
    ),
]


def _laser_pose(value: str | None) -> tuple[float, float, float] | None:
    """A typer callback: ``--laser-pose X,Y,YAW`` as three finite numbers."""
    if value is None:
        return None
    try:
        return parse_laser_pose(value)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


# The read options, in the order ``--help`` shows them; ``with_read_options`` adds them.
_READ_PARAMETERS: tuple[tuple[str, Any, Any], ...] = (
    (
        "poses",
        Annotated[
            Poses,
            typer.Option(
                help="What the scans' pose fields hold "
                "(auto: GMapping output → reference, else odometry)."
            ),
        ],
        Poses.auto,
    ),
    ("fov", FovOpt, 180.0),
    (
        "max_range",
        Annotated[
            float | None,
            typer.Option(
                help="Readings at or beyond this (m, > 0) are no-returns.",
                show_default="the message's, or 95% of the log's largest reading",
                callback=number(0, lo_open=True, optional=True),
            ),
        ],
        None,
    ),
    (
        "laser",
        Annotated[Laser, typer.Option(help="front: FLASER/ROBOTLASER1; rear: RLASER.")],
        Laser.front,
    ),
    (
        "skip_bad_lines",
        Annotated[bool, typer.Option(help="Skip malformed lines and report how many.")],
        False,
    ),
    (
        "scan_topic",
        Annotated[
            str | None,
            typer.Option(
                help="ROS bags: LaserScan topic (unset: the bag's only one; of several, /scan).",
            ),
        ],
        None,
    ),
    ("odom_topic", Annotated[str | None, typer.Option(help="ROS bags: Odometry topic.")], None),
    (
        "laser_pose",
        Annotated[
            str | None,
            typer.Option(
                metavar="X,Y,YAW",
                help="The laser in the robot's base frame: metres ahead, metres left, degrees.",
                show_default="from the bag's /tf_static or /tf, else at the base",
                callback=_laser_pose,
            ),
        ],
        None,
    ),
    (
        "laser_flipped",
        Annotated[
            bool, typer.Option(help="The laser is mounted upside down (its scans are mirrored).")
        ],
        False,
    ),
)


def _read_options(values: dict[str, Any]) -> ReadOptions:
    return ReadOptions(
        poses=values["poses"].value,
        fov_deg=values["fov"],
        max_range=values["max_range"],
        laser=values["laser"].value,
        skip_bad_lines=values["skip_bad_lines"],
        scan_topic=values["scan_topic"],
        odom_topic=values["odom_topic"],
        laser_pose=values["laser_pose"],
        laser_flipped=values["laser_flipped"],
    )


def with_read_options(command: Callable[..., None]) -> Callable[..., None]:
    """Gives a command the read options; it takes them as one parameter ``read: ReadOptions``.

    Example:
        >>> @with_read_options
        ... def info(log: LogArg, read: ReadOptions) -> None: ...
    """
    names = [name for name, _, _ in _READ_PARAMETERS]
    signature = inspect.signature(command, eval_str=True)
    kept = [p for p in signature.parameters.values() if p.name != "read"]
    added = [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=kind)
        for name, kind, default in _READ_PARAMETERS
    ]

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        read = _read_options({name: kwargs.pop(name) for name in names})
        return command(*args, read=read, **kwargs)

    params = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in kept] + added
    wrapper.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
    del wrapper.__wrapped__
    return wrapper


def process_start() -> float:
    """When this process started, on ``time.perf_counter``'s clock: what "ready N s after
    start" counts from, the interpreter's start and the imports included, as a user waits
    for them (Linux's ``/proc``; elsewhere, now)."""
    now = time.perf_counter()
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        ticks = int(fields[19])  # field 22 of stat: the start, in clock ticks after boot
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        return now - max(0.0, uptime - ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return now
