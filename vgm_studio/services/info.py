"""``vgm-studio info``: what a log (or a relations file) holds."""

from __future__ import annotations

import json
from pathlib import Path

from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.datasets.relations import looks_like_relations, read_relations
from vgm_studio.datasets.scans import mount_line
from vgm_studio.datasets.source import reading_warnings
from vgm_studio.datasets.summary import format_summary, summarize
from vgm_studio.matching.agreement import MIN_EDGES, check_log
from vgm_studio.services import Say, quiet


def describe(path: Path, read: ReadOptions, as_json: bool = False, warn: Say = quiet) -> str:
    """A log's scans, beams, field of view, duration, poses and distance, as text or JSON."""
    if path.is_file() and looks_like_relations(path):
        relations = read_relations(path)
        stamps = {r.t_a for r in relations} | {r.t_b for r in relations}
        if as_json:
            doc = {
                "path": str(path),
                "format": "relations",
                "relations": len(relations),
                "timestamps": len(stamps),
            }
            return json.dumps(doc, indent=2)
        return (
            f"{path}: Freiburg relations file, {len(relations)} relations "
            f"between {len(stamps)} scan timestamps"
        )
    log = open_log(path, read)
    for line in reading_warnings(log):
        warn(line)
    summary = summarize(log)
    return json.dumps(summary, indent=2) if as_json else format_summary(summary)


def check(path: Path, read: ReadOptions, as_json: bool = False, warn: Say = quiet) -> str:
    """``info --check``: matches consecutive keyframes and says whether they agree with odometry."""
    log = open_log(path, read)
    for line in reading_warnings(log):
        warn(line)
    agreement = check_log(log)
    mount = mount_line(log)
    if as_json:
        doc = {"path": str(log.path), "mount": mount}
        return json.dumps(doc | {"agreement": agreement and agreement.to_json()}, indent=2)
    if agreement is None or agreement.edges < MIN_EDGES:
        if not any(s.odometry is not None for s in log.scans):
            reason = "the log has no odometry"
        elif agreement is None:
            reason = "the robot does not move"
        else:
            reason = f"only {agreement.edges} matched step(s); {MIN_EDGES} are needed"
        return f"{log.path}: nothing to check ({reason}); laser mount {mount}"
    if agreement.disagrees:
        return agreement.warning(mount)
    return f"{log.path}: scans and odometry agree ({agreement.figures()}); laser mount {mount}"
