"""Labels out of and into a workspace, as JSONL or CSV.

A row is an edge in the candidates' JSONL schema whose ``label`` is the annotator's, plus
``annotator``, ``labeled_at`` and ``note``; ``reference_label`` keeps the edge's own label from
the reference. An exported JSONL file is also a training file for ``vgm-studio train``.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from datetime import datetime
from pathlib import Path
from typing import Any

from vgm_studio.errors import InputError
from vgm_studio.labels.store import HUMAN_LABELS, LabelRecord, LabelStore
from vgm_studio.matching.edges import Edge

FORMATS = (".jsonl", ".csv")
_NESTED = ("guess", "estimate", "reference", "match", "params")
COLUMNS = (
    "edge_id",
    "annotator",
    "label",
    "labeled_at",
    "note",
    "reference_label",
    "kind",
    "a",
    "b",
    "timestamp_a",
    "timestamp_b",
    "log_path",
    "log_sha256",
    *_NESTED,
)


def _check_format(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise InputError(
            path, f"unknown label file type {suffix or '(none)'!r}; use .jsonl or .csv"
        )
    return suffix


def label_rows(store: LabelStore) -> list[dict[str, Any]]:
    """Every current label of the store as an export row, in log order."""
    edges: dict[str, Edge] = {}
    rows = []
    for record in store.labels():
        edge = edges.get(record.edge_id) or store.edge(record.edge_id)
        edges[record.edge_id] = edge
        row = edge.to_json()
        row["reference_label"] = row.pop("label")
        row.update(
            label=record.label,
            annotator=record.annotator,
            labeled_at=record.labeled_at,
            note=record.note,
        )
        rows.append(row)
    return rows


def export_labels(store: LabelStore, out: Path) -> int:
    """Writes the store's labels to ``out`` (.jsonl or .csv) atomically. Returns the count."""
    suffix = _check_format(out)
    rows = label_rows(store)
    if suffix == ".jsonl":
        text = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows)
    else:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: json.dumps(row[k]) if k in _NESTED else row[k] for k in COLUMNS})
        text = buffer.getvalue()
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return len(rows)


def _read_rows(path: Path) -> list[tuple[int, dict[str, Any]]]:
    if not path.is_file():
        raise InputError(path, "no such file")
    suffix = _check_format(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    rows: list[tuple[int, dict[str, Any]]] = []
    if suffix == ".jsonl":
        for lineno, line in enumerate(text.splitlines(), start=1):
            if line.strip():
                try:
                    rows.append((lineno, json.loads(line)))
                except json.JSONDecodeError as exc:
                    raise InputError(path, f"not JSON ({exc.msg})", line=lineno) from None
        return rows
    reader = csv.DictReader(io.StringIO(text, newline=""))
    missing = [
        c
        for c in ("edge_id", "annotator", "label", "labeled_at")
        if c not in (reader.fieldnames or [])
    ]
    if missing:
        raise InputError(path, f"CSV header lacks {', '.join(missing)}", line=1)
    for row in reader:
        lineno = reader.line_num
        parsed: dict[str, Any] = dict(row)
        for key in _NESTED:
            if row.get(key):
                try:
                    parsed[key] = json.loads(row[key])
                except json.JSONDecodeError:
                    raise InputError(path, f"column {key} is not JSON", line=lineno) from None
        for key in ("timestamp_a", "timestamp_b"):
            parsed[key] = float(row[key]) if row.get(key) else None
        parsed["reference_label"] = row.get("reference_label") or None
        rows.append((lineno, parsed))
    return rows


def import_labels(store: LabelStore, path: Path) -> tuple[int, int]:
    """Adds a label file's edges and labels to the store; a newer label wins.

    The whole file is checked before anything is written, so a bad line changes nothing.

    Returns:
        (edges added, labels added or updated).

    Raises:
        InputError: A line is not an exported label (names the file and line).
    """
    edges: list[Edge] = []
    records: list[LabelRecord] = []
    for lineno, row in _read_rows(path):
        if not isinstance(row, dict):
            raise InputError(path, "a label row must be a JSON object", line=lineno)
        annotator = row.get("annotator")
        if not isinstance(annotator, str) or not annotator.strip():
            raise InputError(path, "row has no annotator (is this an exported label file?)", lineno)
        if row.get("label") not in HUMAN_LABELS:
            raise InputError(
                path, f"label {row.get('label')!r} is not one of {', '.join(HUMAN_LABELS)}", lineno
            )
        labeled_at = row.get("labeled_at")
        try:
            datetime.fromisoformat(str(labeled_at))
        except ValueError:
            raise InputError(
                path, f"labeled_at {labeled_at!r} is not an ISO time", lineno
            ) from None
        edge_obj = {**row, "label": row.get("reference_label")}
        edges.append(Edge.from_json(edge_obj, path, lineno))
        records.append(
            LabelRecord(
                str(row["edge_id"]),
                annotator,
                row["label"],
                str(row.get("note") or ""),
                str(labeled_at),
            )
        )
    if not records:
        raise InputError(path, "holds no labels")
    added = store.add_edges(edges)
    changed = sum(store.import_label(r) for r in records)
    return added, changed
