"""``vgm-studio compare``: two runs' ``--json`` compared, the maps drawn over each other, the
rules judged.

The comparison is the JSON alone (a second or less on Intel). The picture needs the maps,
which the JSON does not hold: it reads the log the runs name again (by the path in the new
run's JSON, or ``log``) and draws each run's keyframe scans at its after poses. A CI job has
that log, since it has just run ``slam`` on it; a baseline JSON kept in the repository then
suffices, where a map picture kept beside it would go stale with every change of resolution
and has to be regenerated with the baseline anyway.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from vgm_studio.atomic import write_text_atomically
from vgm_studio.compare import (
    CompareConfig,
    Comparison,
    Outcome,
    Run,
    check_rules,
    compare_runs,
    load_run,
    parse_rules,
    same_subject,
)
from vgm_studio.compare.overlay import overlay
from vgm_studio.compare.page import markdown, text_report
from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.errors import InputError
from vgm_studio.maps.config import MapConfig
from vgm_studio.maps.occupancy import OccupancyGrid, build_map
from vgm_studio.maps.png import write_png
from vgm_studio.services import Voice


@dataclass(frozen=True)
class CompareOutputs:
    """What a comparison writes and links to.

    Attributes:
        png: The two after maps over each other.
        markdown: The CI summary page.
        studio_url: The studio's address (``http://HOST:PORT``); listed loops link to it.
        log: The log the runs read, where it is not at the path their JSON names.
        resolution: Cell edge of the maps, metres.
    """

    png: Path | None = None
    markdown: Path | None = None
    studio_url: str | None = None
    log: Path | None = None
    resolution: float = 0.05


@dataclass
class CompareResult:
    """A comparison and its rules' outcomes; ``failed`` lists the rules that do not hold."""

    comparison: Comparison
    outcomes: list[Outcome] = field(default_factory=list)

    @property
    def failed(self) -> list[Outcome]:
        return [o for o in self.outcomes if not o.holds]


def run_compare(
    base: Path,
    new: Path,
    config: CompareConfig,
    rules: str = "",
    outputs: CompareOutputs | None = None,
    voice: Voice | None = None,
) -> CompareResult:
    """Compares two runs, writes what ``outputs`` asks and judges ``rules``.

    Every input is checked before anything is written, so bad input leaves no half report.

    Raises:
        InputError: A missing or unreadable file, a document that is not a run, runs of two
            different logs, an unknown or malformed rule, a log that cannot be found for the
            picture.
    """
    outputs = outputs or CompareOutputs()
    voice = voice or Voice()
    parsed = parse_rules(rules)
    runs = load_run(base), load_run(new)
    same_subject(*runs)
    comparison = compare_runs(*runs, config)
    result = CompareResult(comparison, check_rules(parsed, comparison))
    picture = None
    if outputs.png is not None:
        picture = _write_overlay(outputs.png, runs, outputs)
        voice.say(f"wrote {outputs.png}")
    voice.say(text_report(comparison, result.outcomes))
    if outputs.markdown is not None:
        shown = None if picture is None else _relative(picture, outputs.markdown.parent)
        page = markdown(comparison, result.outcomes, shown, outputs.studio_url)
        _write_text(outputs.markdown, page)
        voice.say(f"wrote {outputs.markdown}")
    return result


def _relative(path: Path, folder: Path) -> Path:
    """``path`` as the page beside it links it: relative where it can be."""
    try:
        return Path(os.path.relpath(path.resolve(), folder.resolve()))
    except ValueError:  # another drive on Windows
        return path


def _write_text(path: Path, text: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomically(path, text + "\n")
    except OSError as exc:
        raise InputError(path, f"cannot write it ({exc.strerror or exc})") from None


def _write_overlay(path: Path, runs: tuple[Run, Run], outputs: CompareOutputs) -> Path:
    new = runs[1]
    if new.kind != "slam" or new.keyframe_scans is None:
        raise InputError(new.path, "--png needs two slam runs: an audit's JSON holds no poses")
    log_path = outputs.log or Path(str(new.log_path))
    if not log_path.is_file():
        raise InputError(
            log_path, "the runs' log is not here to draw the maps from; name it with --log"
        )
    try:
        read = ReadOptions(**new.read)
    except TypeError:
        raise InputError(new.path, "the run's read options are not this version's") from None
    log = open_log(log_path, read)
    if log.content_hash != new.identity:
        raise InputError(log_path, f"not the log the runs read ({new.subject})")
    config = MapConfig(resolution=outputs.resolution)
    grids = [_after_map(log, run, config) for run in runs]
    if grids[0].resolution != grids[1].resolution:
        # A map over max_cells is drawn coarser; both must share the coarser cells.
        coarse = MapConfig(resolution=max(g.resolution for g in grids))
        grids = [_after_map(log, run, coarse) for run in runs]
    write_png(path, overlay(*grids))
    return path


def _after_map(log: ScanLog, run: Run, config: MapConfig) -> OccupancyGrid:
    """The after map of one run: its keyframe scans at its after poses."""
    assert run.keyframe_scans is not None and run.after_poses is not None
    if len(run.keyframe_scans) and int(run.keyframe_scans.max()) >= len(log.scans):
        raise InputError(run.path, f"names scan {int(run.keyframe_scans.max())}; the log has fewer")
    points = [log.scans[int(k)].points() for k in run.keyframe_scans]
    return build_map(run.after_poses, points, config)
