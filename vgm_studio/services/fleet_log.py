"""One log of a fleet: candidates, their validation, a SLAM run, and the log's row.

This is what a fleet worker does for each log, with the same services the single-log
commands call (``candidates``, ``slam``), so a log's figures here are those commands'
figures. Everything is written into the log's own folder; the row is the last file written,
so a folder with ``row.json`` is a finished log.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vgm_studio.atomic import write_text_atomically
from vgm_studio.core.hashing import content_hash
from vgm_studio.datasets import ReadOptions
from vgm_studio.datasets.manifest import ManifestEntry
from vgm_studio.datasets.source import JoinOptions
from vgm_studio.matching.candidates import CandidateConfig
from vgm_studio.matching.reference_labels import LabelThresholds
from vgm_studio.model.cache import shared_validator
from vgm_studio.model.metrics import binary_metrics
from vgm_studio.services.candidates import make_edge_file
from vgm_studio.services.outputs import RunFiles
from vgm_studio.services.slam import SlamOutputs, run_slam_command
from vgm_studio.slam.config import SlamConfig
from vgm_studio.slam.edges import LOOP_SOURCES

# Bumped when a row's meaning changes, so older rows are made again rather than mixed in.
ROW_FORMAT = 1
ROW_FILE = "row.json"
RUNNING_FILE = "running.json"


@dataclass(frozen=True)
class FleetSettings:
    """Everything a log's figures depend on besides the log itself.

    Attributes:
        slam: The SLAM run; its validation model also validates the candidates.
        candidates: Which candidate edges are made.
        thresholds: What the reference calls a success or a failure.
        read: How logs are read.
        join: How a reference log is joined to the scans.
    """

    slam: SlamConfig = field(default_factory=SlamConfig)
    candidates: CandidateConfig = field(default_factory=CandidateConfig)
    thresholds: LabelThresholds = field(default_factory=LabelThresholds)
    read: ReadOptions = field(default_factory=ReadOptions)
    join: JoinOptions = field(default_factory=JoinOptions)

    @property
    def model(self) -> Path:
        model = self.slam.validation.model
        assert model is not None, "a fleet validates with a model"
        return model

    def key_doc(self) -> dict[str, Any]:
        """The settings as JSON, the model by its content rather than its path."""
        doc: dict[str, Any] = json.loads(json.dumps(asdict(self), default=str))
        doc["slam"]["validation"]["model"] = content_hash(self.model)
        return doc


def log_key(entry: ManifestEntry, settings: FleetSettings) -> tuple[str, str]:
    """The log's sha256, and the key of its results: the log, its references, the settings.

    Raises:
        OSError: A file cannot be read.
    """
    log_sha = content_hash(entry.log)
    doc = {
        "format": ROW_FORMAT,
        "log": log_sha,
        "reference": content_hash(entry.reference) if entry.reference else None,
        "relations": content_hash(entry.relations) if entry.relations else None,
        "settings": settings.key_doc(),
    }
    text = json.dumps(doc, sort_keys=True).encode()
    return log_sha, hashlib.sha256(text).hexdigest()


def log_folder(out: Path, entry: ManifestEntry) -> Path:
    return out / "logs" / entry.name


def finished_row(out: Path, entry: ManifestEntry, key: str) -> dict[str, Any] | None:
    """The row of an earlier run with the same key that succeeded, if any."""
    path = log_folder(out, entry) / ROW_FILE
    try:
        row = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(row, dict) or row.get("key") != key or row.get("status") != "done":
        return None
    return row


def base_row(entry: ManifestEntry, log_sha: str, key: str) -> dict[str, Any]:
    """The columns every row has, done or failed."""
    return {
        "name": entry.name,
        "log": str(entry.log),
        "reference": str(entry.reference) if entry.reference else None,
        "relations": str(entry.relations) if entry.relations else None,
        "log_sha256": log_sha,
        "key": key,
        "status": "failed",
        "error": None,
    }


def process_log(
    entry: ManifestEntry, settings: FleetSettings, out: Path, log_sha: str, key: str
) -> dict[str, Any]:
    """Runs the log through candidates, validation and SLAM; returns its row.

    Raises:
        InputError: The log or a reference cannot be read, or an output cannot be written.
    """
    start = time.perf_counter()
    folder = log_folder(out, entry)
    folder.mkdir(parents=True, exist_ok=True)
    row = base_row(entry, log_sha, key)
    run = make_edge_file(
        entry.log,
        folder / "edges.jsonl",
        settings.read,
        entry.reference or entry.relations,
        settings.join,
        settings.candidates,
        settings.thresholds,
    )
    row.update(_candidate_columns(run.edges))
    row.update(_validation_columns(run.edges, settings, folder / "predictions.csv"))
    slam_json, maps = folder / "slam.json", folder / "maps"
    maps.mkdir(exist_ok=True)
    run_slam_command(
        entry.log,
        settings.read,
        settings.slam,
        reference=entry.reference,
        relations=entry.relations,
        join=settings.join,
        outputs=SlamOutputs(json=slam_json, files=RunFiles(maps=maps)),
    )
    row.update(slam_columns(json.loads(slam_json.read_text(encoding="utf-8"))))
    row.update(
        status="done",
        edges_file=str(folder / "edges.jsonl"),
        slam_json=str(slam_json),
        after_png=str(maps / "after.png"),
        seconds=time.perf_counter() - start,
    )
    return row


def _candidate_columns(edges: list[Any]) -> dict[str, Any]:
    labels = [e.label for e in edges]
    return {
        "candidates": len(edges),
        "candidates_loop": sum(e.kind == "loop" for e in edges),
        "labelled_success": labels.count("success"),
        "labelled_failure": labels.count("failure"),
    }


def _validation_columns(edges: list[Any], settings: FleetSettings, out: Path) -> dict[str, Any]:
    """The model's p(success) of every candidate, and its figures against the labels."""
    validator = shared_validator(settings.model)
    p = validator.predict(edges, progress=False) if edges else np.zeros(0)
    lines = [f"{e.edge_id},{pe:.6f}\n" for e, pe in zip(edges, p, strict=True)]
    write_text_atomically(out, "edge_id,p_success\n" + "".join(lines))
    keep = validator.decide(p)
    cols: dict[str, Any] = {
        "model": validator.name,
        "model_threshold": validator.threshold,
        "predicted_success": int(keep.sum()),
        "predicted_failure": int((~keep).sum()),
        "accuracy": None,
        "f1": None,
    }
    labelled = np.array([e.label in ("success", "failure") for e in edges], dtype=bool)
    if labelled.any():
        truth = np.array([e.label == "success" for e in edges], dtype=bool)[labelled]
        m = binary_metrics(truth, p[labelled], validator.threshold)
        cols.update(accuracy=_finite(m["accuracy"]), f1=_finite(m["f1"]))
    return cols


def slam_columns(doc: dict[str, Any]) -> dict[str, Any]:
    """A SLAM run's figures as table columns, read from its ``--json`` document.

    The relation errors are null when the log had no relations to be scored by.
    """
    cols: dict[str, Any] = {
        "scans": doc["scans"],
        "keyframes": doc["keyframes"],
        "edges_total": doc["edges_total"],
        "edges_kept": doc["edges_kept"],
        "loops_total": doc["loops_total"],
        "loops_kept": doc["loops_kept"],
        "loops_rejected": doc["loops_total"] - doc["loops_kept"],
        # Where loops came from and who turned them down, when the run says so (null if not).
        "loops_validator_kept": doc.get("loops_validator_kept"),
        "loops_consistency_rejected": doc.get("loops_consistency_rejected"),
    }
    for source in LOOP_SOURCES:
        cols[f"loops_by_{source}"] = (doc.get("loops_by_source") or {}).get(source)
    for trajectory in ("odometry", "before", "after"):
        errors = doc.get(trajectory) or {}
        cols[f"{trajectory}_trans_mean_m"] = errors.get("trans_mean")
        cols[f"{trajectory}_rot_mean_deg"] = errors.get("rot_mean_deg")
    cols["after_trans_std_m"] = (doc.get("after") or {}).get("trans_std")
    cols["relations_n"] = (doc.get("after") or {}).get("n")
    return cols


def _finite(value: Any) -> float | None:
    return float(value) if value is not None and np.isfinite(value) else None
