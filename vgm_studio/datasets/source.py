"""A log read with its reference: the scans, the matched relations, and what went amiss.

``candidates``, ``label`` and ``slam`` read a log the same way: the log itself, then a
corrected log or a TRUEPOS log joined by timestamp, or a Freiburg relations file matched to
scan pairs. What a person should hear about (lines skipped, scans left unjoined) comes back
as ``warnings``, one line each, for the caller to print.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from vgm_studio.datasets import ReadOptions, ScanLog, open_log
from vgm_studio.datasets.reference import with_reference
from vgm_studio.datasets.relations import (
    MatchedRelation,
    looks_like_relations,
    match_relations,
    read_relations,
)
from vgm_studio.errors import InputError


@dataclass(frozen=True)
class JoinOptions:
    """How a reference log is joined to the scans.

    Attributes:
        time_tolerance: Reference timestamps match within this many seconds.
        time_offset: Seconds added to the reference log's timestamps before the join.
    """

    time_tolerance: float = 0.05
    time_offset: float = 0.0


@dataclass
class LogSource:
    """A log and its reference, read.

    Attributes:
        log: The scans (with reference poses when a reference log was joined).
        relations: Relations matched to scan pairs, when a relations file was given.
        params: Provenance kept with the edges made from it.
        warnings: One line each, for a person.
    """

    log: ScanLog
    relations: list[MatchedRelation] | None
    params: dict[str, Any]
    warnings: list[str] = field(default_factory=list)


def skipped_lines(log: ScanLog) -> list[str]:
    """What ``--skip-bad-lines`` passed over, as a warning (none when nothing was skipped)."""
    if not log.skipped_lines:
        return []
    lines = log.skipped_line_numbers
    shown = ", ".join(map(str, lines[:5])) + (", …" if len(lines) > 5 else "")
    where = f" (line{'s' if len(lines) > 1 else ''} {shown})" if lines else ""
    return [f"{log.path}: skipped {log.skipped_lines} malformed line(s){where}"]


def reading_warnings(log: ScanLog) -> list[str]:
    """Everything the reader has to say about a log: lines skipped, topics chosen."""
    return skipped_lines(log) + log.warnings


def read_log(path: Path, options: ReadOptions, relations_go_to: str = "--reference") -> LogSource:
    """Reads a log alone, refusing a relations file given in its place.

    Raises:
        InputError: ``path`` is a relations file, or cannot be read.
    """
    if path.is_file() and looks_like_relations(path):
        where = f"pass it as {relations_go_to}"
        if relations_go_to == "--reference":
            where += ", after the log"
        raise InputError(path, f"this is a Freiburg relations file; {where}")
    log = open_log(path, options)
    params: dict[str, Any] = {"read": asdict(options), "reference_source": "log"}
    return LogSource(log, None, params, reading_warnings(log))


def read_source(
    log_path: Path,
    options: ReadOptions,
    reference: Path | None = None,
    join: JoinOptions | None = None,
    max_loops: int | None = None,
) -> LogSource:
    """Reads a log and joins its reference: a corrected log, a TRUEPOS log or relations.

    Args:
        log_path: The log.
        options: How to read it.
        reference: A corrected log, a log with TRUEPOS, or a Freiburg relations file.
        join: How a reference log is joined.
        max_loops: Loop edges kept at most (said in a warning when relations give more).

    Raises:
        InputError: The log is a relations file, or nothing of the reference matches it.
    """
    join = join or JoinOptions()
    source = read_log(log_path, options)
    if reference is not None:
        source.params["reference_source"] = str(reference.resolve())
        if looks_like_relations(reference):
            _add_relations(source, reference, min(join.time_tolerance, 1e-3), max_loops)
        else:
            source.params["time_offset"] = join.time_offset
            _join_reference(source, reference, join, options)
            joined = sum(s.reference is not None for s in source.log.scans)
            if joined < len(source.log):
                source.warnings.append(
                    f"{reference}: {joined} of {len(source.log)} scans joined a reference pose; "
                    "edges are made between those scans"
                )
    if source.relations is None and not any(s.reference is not None for s in source.log.scans):
        source.warnings.append(
            f"{log_path}: no reference poses found (a raw log, no TRUEPOS, no --reference), so "
            "edges are unlabelled and loop pairs come from odometry"
        )
    return source


def read_slam_source(
    log_path: Path,
    options: ReadOptions,
    reference: Path | None = None,
    relations: Path | None = None,
    join: JoinOptions | None = None,
) -> LogSource:
    """Reads a log for a SLAM run: reference poses to validate by, relations to score by.

    Raises:
        InputError: A relations file where a log is due or the other way round, or
            relations that match no scan pair.
    """
    source = read_log(log_path, options, relations_go_to="--relations")
    attach_reference(source, options, reference, relations, join)
    return source


def attach_reference(
    source: LogSource,
    options: ReadOptions,
    reference: Path | None = None,
    relations: Path | None = None,
    join: JoinOptions | None = None,
) -> None:
    """Joins a reference log's poses to ``source``'s scans and matches a relations file to
    them, as a SLAM run is scored (``read_slam_source``; ``audit`` too, on a graph's scans).

    Raises:
        InputError: A relations file where a log is due or the other way round, or
            relations that match no scan pair.
    """
    if relations is not None:
        if relations.is_file() and not looks_like_relations(relations):
            raise InputError(
                relations,
                "is not a Freiburg relations file (t1 t2 x y z roll pitch yaw on each line)",
            )
        _add_relations(source, relations)
    if reference is not None:
        if looks_like_relations(reference):
            raise InputError(
                reference,
                "relations give no pose per scan; --reference takes a corrected log or a "
                "log with TRUEPOS (relations go to --relations)",
            )
        _join_reference(source, reference, join or JoinOptions(), options)


def _join_reference(
    source: LogSource, reference: Path, join: JoinOptions, options: ReadOptions
) -> None:
    # The log's mount reads the reference too: a CARMEN reference's poses are the laser's,
    # like the log's, and both must move to the base alike for labels to compare one frame.
    mount = ReadOptions(laser_pose=options.laser_pose, laser_flipped=options.laser_flipped)
    source.log = with_reference(
        source.log,
        open_log(reference, mount),
        join.time_tolerance,
        join.time_offset,
    )


def _add_relations(
    source: LogSource, path: Path, tolerance: float = 1e-3, max_loops: int | None = None
) -> None:
    """Matches a relations file's pairs to the log's scans by timestamp."""
    found = read_relations(path)
    matched, missed = match_relations(found, source.log.timestamps, tolerance=tolerance)
    if not matched:
        raise InputError(path, f"no relation matches scans of {source.log.path} by timestamp")
    if missed:
        source.warnings.append(f"{path}: {missed} relation(s) match no scan pair")
    if max_loops is not None and len(matched) > max_loops:
        source.warnings.append(
            f"{path}: kept {max_loops} of {len(matched)} relations as loop edges (--max)"
        )
    source.relations = matched
