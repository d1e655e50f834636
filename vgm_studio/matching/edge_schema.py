"""The schema of an edge as it is written to a JSONL file, declared once.

Every reader of an edge (``read_edges``, the label store, ``import``) parses through
``EdgeRow``: types, finite numbers, ranges, string lengths and encodings are checked here, and
a failure becomes one ``file:line: field: what is wrong`` line. ``load_json_line`` is the one
way a line of untrusted JSON is parsed: it refuses what Python's ``json`` would take (``NaN``,
``Infinity``) or choke on (deep nesting, huge integers, huge lines) without a traceback.
"""

from __future__ import annotations

import json
import math
import unicodedata
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    ValidationError,
)

from vgm_studio.errors import InputError

# A line of an edges file is about 2 kB; a thousand times that is no edge.
MAX_LINE_CHARS = 2_000_000
# Edges nest three levels (params → candidates → value); anything deeper is not ours.
MAX_DEPTH = 16
MAX_PATH_CHARS = 4096
MAX_TEXT_CHARS = 256
# No log holds a billion scans, and no pose is a thousand kilometres from its pair.
MAX_SCAN_INDEX = 1_000_000_000
MAX_COORDINATE = 1e6
MAX_ANGLE = 2 * math.pi + 1e-6


def _utf8(value: str) -> str:
    """Refuses text UTF-8 cannot hold (a lone surrogate such as ``\\ud800``)."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError("holds a lone surrogate (not UTF-8 text)") from None
    if "\x00" in value:
        raise ValueError("holds a NUL character")
    return value


def _printable(value: str) -> str:
    """Refuses control characters in a name that messages quote (escape sequences, NUL)."""
    if any(unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co", "Cn") for c in value):
        raise ValueError("holds control characters")
    return value


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError("must be a finite number")
    return value


def _pose(value: list[float]) -> list[float]:
    if len(value) != 3:
        raise ValueError("must be three finite numbers [x, y, theta]")
    x, y, theta = (float(v) for v in value)
    if not all(math.isfinite(v) for v in (x, y, theta)):
        raise ValueError("must be three finite numbers [x, y, theta]")
    if max(abs(x), abs(y)) > MAX_COORDINATE or abs(theta) > MAX_ANGLE:
        raise ValueError(
            f"must be [x, y, theta] with |x|, |y| ≤ {MAX_COORDINATE:g} m and |theta| ≤ 2π"
        )
    return [x, y, theta]


Text = Annotated[str, Field(max_length=MAX_TEXT_CHARS), AfterValidator(_utf8)]
# Names appear in messages and file paths: no control characters at all.
Name = Annotated[Text, AfterValidator(_printable)]
PathText = Annotated[
    str,
    Field(min_length=1, max_length=MAX_PATH_CHARS),
    AfterValidator(_utf8),
    AfterValidator(_printable),
]
Finite = Annotated[float, AfterValidator(_finite)]
Pose = Annotated[list[float], AfterValidator(_pose)]
ScanIndex = Annotated[int, Field(ge=0, le=MAX_SCAN_INDEX)]
Probability = Annotated[float, Field(ge=0.0, le=1.0)]


class MatchFigures(BaseModel):
    """The matcher's figures (``MatchResult.figures``); unknown keys are kept as they are."""

    model_config = ConfigDict(extra="allow")

    iterations: Annotated[int, Field(ge=0, le=1_000_000)] | None = None
    converged: StrictBool | None = None
    inlier_ratio: Probability | None = None
    residual: Annotated[Finite, Field(ge=0.0)] | None = None
    covariance: (
        Annotated[
            list[Annotated[list[Finite], Field(min_length=3, max_length=3)]],
            Field(min_length=3, max_length=3),
        ]
        | None
    ) = None
    kiss_estimate: Annotated[list[Finite], Field(min_length=3, max_length=3)] | None = None
    kiss_moved: Annotated[Finite, Field(ge=0.0)] | None = None
    kiss_turned: Annotated[Finite, Field(ge=0.0)] | None = None


class ReadParams(BaseModel):
    """How the log was read (``ReadOptions``): the studio reopens the log with these."""

    model_config = ConfigDict(extra="forbid")

    poses: Literal["auto", "odometry", "reference"] = "auto"
    fov_deg: Annotated[Finite, Field(gt=0.0, le=360.0)] = 180.0
    max_range: Annotated[Finite, Field(gt=0.0)] | None = None
    laser: Literal["front", "rear"] = "front"
    skip_bad_lines: StrictBool = False
    scan_topic: Name | None = None
    odom_topic: Name | None = None
    laser_pose: Annotated[list[Finite], Field(min_length=3, max_length=3)] | None = None
    laser_flipped: StrictBool = False


class EdgeParams(BaseModel):
    """How the edge was made; only ``read`` is used again, the rest is provenance."""

    model_config = ConfigDict(extra="allow")

    read: ReadParams | None = None


class EdgeRow(BaseModel):
    """One line of an edges file (see ``Edge`` for the meaning of each field)."""

    model_config = ConfigDict(extra="ignore")

    edge_id: Annotated[Name, Field(min_length=1, max_length=128)]
    log_path: PathText
    log_sha256: Annotated[Name, Field(max_length=MAX_TEXT_CHARS)] = ""
    a: ScanIndex
    b: ScanIndex
    timestamp_a: Finite | None = None
    timestamp_b: Finite | None = None
    kind: Literal["sequential", "loop"]
    guess: Pose
    estimate: Pose
    match: MatchFigures = Field(default_factory=MatchFigures)
    reference: Pose | None = None
    label: Literal["success", "failure", "ambiguous"] | None = None
    params: EdgeParams = Field(default_factory=EdgeParams)


def _depth(obj: Any) -> int:
    """Nesting depth of parsed JSON, without recursion."""
    deepest, stack = 0, [(obj, 1)]
    while stack:
        value, level = stack.pop()
        deepest = max(deepest, level)
        if isinstance(value, dict):
            stack.extend((v, level + 1) for v in value.values())
        elif isinstance(value, list):
            stack.extend((v, level + 1) for v in value)
    return deepest


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def json_lines(text: str) -> list[str]:
    """The lines of a JSONL text, split at ``\\n`` only.

    ``str.splitlines`` also splits at characters JSON strings may hold raw (U+2028, U+0085,
    form feed), which would cut one record in two.
    """
    return [line.removesuffix("\r") for line in text.split("\n")]


def load_json_line(text: str, path: Path | str | None, line: int | None) -> Any:
    """Parses one line of untrusted JSON.

    Raises:
        InputError: The line is too long, not JSON, holds ``NaN``/``Infinity``, an integer
            of thousands of digits, or nests deeper than ``MAX_DEPTH``.
    """
    if len(text) > MAX_LINE_CHARS:
        raise InputError(path, f"line is {len(text)} characters, over {MAX_LINE_CHARS}", line)
    try:
        obj = json.loads(text, parse_constant=_refuse_constant)
    except RecursionError:
        raise InputError(path, f"not JSON we read (nested deeper than {MAX_DEPTH})", line) from None
    except json.JSONDecodeError as exc:
        # json's own wording of some errors ends in "at" ("Unterminated string starting at").
        what = exc.msg.removesuffix(" at")
        raise InputError(path, f"not JSON ({what} at column {exc.colno})", line) from None
    except ValueError as exc:  # NaN/Infinity, or an integer past Python's digit limit
        reason = "an integer too long" if "digits" in str(exc) else str(exc)
        raise InputError(path, f"not JSON we read ({reason})", line) from None
    if _depth(obj) > MAX_DEPTH:
        raise InputError(path, f"not JSON we read (nested deeper than {MAX_DEPTH})", line)
    return obj


def describe(error: ValidationError) -> str:
    """The first problem of a validation as ``field: what is wrong``, quoting no input."""
    first = error.errors(include_url=False, include_input=False)[0]
    where = ".".join(str(p) for p in first["loc"]) or "row"
    if first["type"] == "missing":
        return f"{where}: missing"
    message = first["msg"].removeprefix("Value error, ")
    return f"{where}: {message}"


def parse_edge_row(obj: Any, path: Path | str | None, line: int | None) -> EdgeRow:
    """Validates one parsed edge object.

    Raises:
        InputError: ``file:line: field: what is wrong``.
    """
    if not isinstance(obj, dict):
        raise InputError(path, "an edge must be a JSON object", line)
    try:
        return EdgeRow.model_validate(obj)
    except ValidationError as exc:
        raise InputError(path, describe(exc), line) from None
