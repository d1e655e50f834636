"""A log and its reference, read for making candidate edges (shared by `candidates` and `label`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import typer

from vgm_studio.datasets import ReadOptions, ScanLog, open_log
from vgm_studio.datasets.relations import MatchedRelation
from vgm_studio.errors import InputError
from vgm_studio.matching.agreement import Agreement, check_agreement, motions_of
from vgm_studio.matching.edges import Edge


@dataclass
class CandidateSource:
    """What ``make_candidates`` needs: the scans, the matched relations, the provenance."""

    log: ScanLog
    relations: list[MatchedRelation] | None
    params: dict[str, Any]


def report_skipped(log: ScanLog) -> None:
    """Says on stderr how many malformed lines ``--skip-bad-lines`` passed over."""
    if log.skipped_lines:
        lines = log.skipped_line_numbers
        shown = ", ".join(map(str, lines[:5])) + (", …" if len(lines) > 5 else "")
        where = f" (line{'s' if len(lines) > 1 else ''} {shown})" if lines else ""
        typer.echo(f"{log.path}: skipped {log.skipped_lines} malformed line(s){where}", err=True)


def read_source(
    log_path: Path,
    options: ReadOptions,
    reference: Path | None = None,
    *,
    time_tolerance: float = 0.05,
    time_offset: float = 0.0,
    max_loops: int | None = None,
) -> CandidateSource:
    """Reads a log and joins its reference: a corrected log, a TRUEPOS log or relations.

    Raises:
        InputError: The log is a relations file, or nothing of the reference matches it.
    """
    from vgm_studio.datasets.reference import with_reference
    from vgm_studio.datasets.relations import looks_like_relations, match_relations, read_relations

    if log_path.is_file() and looks_like_relations(log_path):
        raise InputError(
            log_path, "this is a Freiburg relations file; pass it as --reference, after the log"
        )
    scan_log = open_log(log_path, options)
    report_skipped(scan_log)
    params: dict[str, Any] = {"read": asdict(options), "reference_source": "log"}
    matched = None
    if reference is not None:
        params["reference_source"] = str(reference.resolve())
        if looks_like_relations(reference):
            matched, missed = match_relations(
                read_relations(reference), scan_log.timestamps, tolerance=min(time_tolerance, 1e-3)
            )
            if not matched:
                raise InputError(reference, f"no relation matches scans of {log_path} by timestamp")
            if missed:
                typer.echo(f"{reference}: {missed} relation(s) match no scan pair", err=True)
            if max_loops is not None and len(matched) > max_loops:
                typer.echo(
                    f"{reference}: kept {max_loops} of {len(matched)} relations as loop "
                    "edges (--max)",
                    err=True,
                )
        else:
            params["time_offset"] = time_offset
            ref_log = open_log(reference, mount_options(options))
            scan_log = with_reference(scan_log, ref_log, time_tolerance, time_offset)
            joined = sum(s.reference is not None for s in scan_log.scans)
            if joined < len(scan_log):
                typer.echo(
                    f"{reference}: {joined} of {len(scan_log)} scans joined a reference pose; "
                    "edges are made between those scans",
                    err=True,
                )
    if matched is None and not any(s.reference is not None for s in scan_log.scans):
        typer.echo(
            f"{log_path}: no reference poses found (a raw log, no TRUEPOS, no --reference), so "
            "edges are unlabelled and loop pairs come from odometry",
            err=True,
        )
    return CandidateSource(scan_log, matched, params)


def mount_options(options: ReadOptions) -> ReadOptions:
    """Options for reading a reference log: the log's mount, so that both logs' poses are of
    the base (a CARMEN reference's poses are the laser's, like the log's)."""
    return ReadOptions(laser_pose=options.laser_pose, laser_flipped=options.laser_flipped)


def mount_line(log: ScanLog) -> str:
    """The mount a log's scans are placed by, and where it came from, for people to read."""
    source = log.mount_source or "no tf in this log and no --laser-pose"
    if log.mount is None:
        return f"at the base ({source})"
    return f"{log.mount.describe()} ({source})"


def report_agreement(log: ScanLog, agreement: Agreement | None) -> None:
    """Prints the one warning when the scans and the odometry disagree."""
    if agreement is not None and agreement.disagrees:
        typer.echo(agreement.warning(mount_line(log)), err=True)


def warn_if_disagreeing(log: ScanLog, edges: Sequence[Edge]) -> Agreement | None:
    """Checks the sequential edges against the log's odometry; warns when they disagree."""
    seq = [e for e in edges if e.kind == "sequential"]
    agreement = check_agreement(
        log,
        motions_of(
            [(e.a, e.b) for e in seq],
            [e.estimate for e in seq],
            [e.match.get("covariance") for e in seq],
        ),
    )
    report_agreement(log, agreement)
    return agreement
