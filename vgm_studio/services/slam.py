"""``vgm-studio slam``: a whole graph-SLAM run with its maps, figures and recording written."""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

from vgm_studio.datasets import ReadOptions
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.datasets.source import JoinOptions, LogSource, read_slam_source
from vgm_studio.errors import InputError
from vgm_studio.matching.agreement import check_agreement, disagreement_warning, motions_of
from vgm_studio.matching.edges import write_edges
from vgm_studio.model.registry import BUNDLED_MODEL, VALIDATOR_MODELS
from vgm_studio.processes import long_lived
from vgm_studio.services import Say, Voice
from vgm_studio.services.outputs import RunFiles, write_json, write_run_files
from vgm_studio.slam.config import SlamConfig
from vgm_studio.slam.loop_edges import loop_edges
from vgm_studio.slam.odometry import has_wheels
from vgm_studio.slam.pipeline import SlamResult, run_slam
from vgm_studio.slam.report import (
    edge_line,
    errors_of,
    summary,
    table,
)
from vgm_studio.slam.scoring import score_by_reference


@dataclass(frozen=True)
class SlamOutputs:
    """What a run writes besides its lines.

    Attributes:
        json: The run's figures as JSON.
        loops: An edges file of the loops the run matched (``slam.loop_edges``).
        loops_injected: ``loops`` holds the injected false loops too.
        files: Maps, recording, trajectory, ROS map and g2o graph (``services.outputs``).
    """

    json: Path | None = None
    loops: Path | None = None
    loops_injected: bool = False
    files: RunFiles = field(default_factory=RunFiles)


def validator_model(validator: str, model: Path | None) -> Path | None:
    """The checkpoint a validator uses: the one given, the bundled one for ``vgmnet``.

    Raises:
        InputError: Another model validator without ``--model``, or a ``--model`` that is
            not a file (said before the log is read, not after).
    """
    if validator in VALIDATOR_MODELS and model is not None and not model.is_file():
        raise InputError(model, "no such model file" if not model.exists() else "not a file")
    if validator not in VALIDATOR_MODELS or model is not None:
        return model
    if validator != "vgmnet":
        raise InputError(
            None,
            f"--validator {validator} needs --model, a checkpoint made by "
            f"vgm-studio train --model {validator}",
        )
    return BUNDLED_MODEL


def run_slam_command(
    log: Path,
    read: ReadOptions,
    config: SlamConfig,
    *,
    reference: Path | None = None,
    relations: Path | None = None,
    join: JoinOptions | None = None,
    outputs: SlamOutputs | None = None,
    voice: Voice | None = None,
) -> None:
    """Reads the log, runs SLAM, scores it against relations and writes what ``outputs`` asks.

    Without a relations file, a log with reference poses (its own, or joined from
    ``reference``) is scored against relations drawn from them (``slam.scoring``).

    Raises:
        InputError: The inputs cannot be read or an output cannot be written.
    """
    start = time.perf_counter()
    outputs = outputs or SlamOutputs()
    voice = voice or Voice()
    say = voice.say
    # A log named as its own reference already holds its reference poses.
    if reference is not None and reference.resolve() == log.resolve():
        reference = None
    source = read_slam_source(log, read, reference, relations, join)
    for line in source.warnings:
        voice.warn(line)
    if score_by_reference(source):
        assert source.relations is not None
        say(f"scored against {len(source.relations)} relations drawn from the reference poses")
    with long_lived():  # the log, and the modules loaded so far
        result = run_slam(source.log, config)
    say(edge_line(result))
    for line in _what_is_missing(source.log, result):
        voice.warn(line)
    errors = errors_of(result, source.relations)
    if errors is not None:
        say(table(errors))
    write_run_files(source.log, result, errors, config.maps, outputs.files, voice)
    if outputs.loops is not None:
        _write_loops(outputs.loops, source, result, say, outputs.loops_injected)
    seconds = time.perf_counter() - start
    if outputs.json is not None:
        settings = json.loads(json.dumps(asdict(config), default=str))
        doc = summary(result, errors, settings, seconds, source.log, source.params.get("read"))
        write_json(outputs.json, doc)
        say(f"wrote {outputs.json}")
    say(f"done in {seconds:.1f} s")


def _write_loops(
    path: Path, source: LogSource, result: SlamResult, say: Say, injected: bool = False
) -> None:
    edges = loop_edges(source.log, result, source.params, injected=injected)
    write_edges(path, edges)
    labels = Counter(e.label or "unlabelled" for e in edges)
    say(
        f"wrote {len(edges)} loops to {path} ("
        + ", ".join(f"{n} {label}" for label, n in sorted(labels.items()))
        + ")"
    )


def _no_loop_closed(log: ScanLog, result: SlamResult) -> list[str]:
    """Why the after map has no loop in it, where it has none: nothing then bounds the drift
    of the sequential matches, and a long run with no loop looks as finished as one with
    many. The counts say at which stage the loops went (the Freiburg hospital's 1.4 km: 5,399
    proposed, 488 placed, 9 passed the validator; its path crosses itself twice and never
    runs a corridor again)."""
    loops = [e for e in result.edges if e.kind == "loop" and not e.injected]
    if any(e.kept for e in loops):
        return []
    metres = f"{log.travelled_distance():.0f} m"
    alone = "the after map is the sequential matches alone and nothing corrects their drift"
    if not loops:
        return [
            f"{log.path}: no loop proposed over {metres}: neither the estimate nor place "
            f"recognition brought the robot back to an earlier place, so {alone}"
        ]
    placed = sum(e.match.covariance is not None for e in loops)
    validated = sum(e.validated for e in loops)
    stages = f"{len(loops)} proposed, {placed} placed by the loop matcher"
    stages += f", {validated} passed the validator"
    if validated:
        stages += ", none kept by the consistency check"
    return [f"{log.path}: no loop closed over {metres} ({stages}): {alone}"]


def _what_is_missing(log: ScanLog, result: SlamResult) -> list[str]:
    """Why a short or still log's outputs are thin, and whether the scans and odometry agree."""
    lines = []
    wheels = has_wheels(log.scans)
    with_odometry = sum(s.odometry is not None for s in log.scans)
    if with_odometry == 0:
        lines.append(f"{log.path}: no odometry in this log; kiss-icp alone gives the motion")
    elif not log.has_odometry:
        # The odometry steers the run only where every scan has it (``slam/odometry.py``), so
        # comparing the matches with the few scans that have some would warn of nothing used.
        lines.append(
            f"{log.path}: odometry on {with_odometry} of {len(log.scans)} scans only; "
            "kiss-icp and the scans alone give the motion"
        )
    elif not wheels:
        lines.append(
            f"{log.path}: the odometry never moves in this log; kiss-icp and the scans alone "
            "give the motion"
        )
    if len(result.keyframes) < 2:
        lines.append(
            f"{log.path}: one keyframe (the robot never moved a keyframe's distance or angle): "
            "no edges and no loops; the maps and recording hold that one scan"
        )
    else:
        lines += _no_loop_closed(log, result)
    if not wheels:
        return lines
    seq = [e for e in result.edges if e.kind == "sequential"]
    keys = result.keyframes
    motions = motions_of(
        [(int(keys[e.a]), int(keys[e.b])) for e in seq],
        [e.estimate for e in seq],
        [e.match.covariance for e in seq],
    )
    disagreement = disagreement_warning(log, check_agreement(log, motions))
    return lines + ([disagreement] if disagreement is not None else [])
