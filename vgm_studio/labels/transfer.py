"""Labels out of and into a workspace, as JSONL or CSV.

A row is an edge in the candidates' JSONL schema whose ``label`` is the annotator's, plus
``annotator``, ``labeled_at`` and ``note``; ``reference_label`` keeps the edge's own label from
the reference. An exported JSONL file is also a training file for ``vgm-studio train``.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vgm_studio.atomic import write_text_atomically
from vgm_studio.errors import InputError
from vgm_studio.labels.schema import escape_cell, parse_label_row, unescape_cell
from vgm_studio.labels.store import LabelRecord, LabelStore
from vgm_studio.matching.edge_scans import check_viewable
from vgm_studio.matching.edge_schema import json_lines, load_json_line
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
    """Writes the store's labels to ``out`` (.jsonl or .csv) atomically. Returns the count.

    Raises:
        InputError: ``out`` has another suffix, or its folder cannot be written.
    """
    suffix = _check_format(out)
    rows = label_rows(store)
    if suffix == ".jsonl":
        text = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows)
    else:
        buffer = io.StringIO()
        # CRLF, as RFC 4180 and spreadsheets write it: the csv module then quotes a cell
        # holding either character, so a note with a carriage return stays one cell.
        writer = csv.DictWriter(buffer, fieldnames=COLUMNS, lineterminator="\r\n")
        writer.writeheader()
        for row in rows:
            writer.writerow(
                {k: json.dumps(row[k]) if k in _NESTED else escape_cell(row[k]) for k in COLUMNS}
            )
        text = buffer.getvalue()
    try:
        write_text_atomically(out, text, newline="")
    except OSError as exc:
        raise InputError(out, f"cannot write here ({exc.strerror or type(exc).__name__})") from None
    return len(rows)


def _read_text(path: Path, suffix: str) -> str:
    if not path.is_file():
        raise InputError(path, "no such file")
    try:
        # Spreadsheets save CSV with a byte-order mark. No newline translation: a carriage
        # return inside a quoted cell is part of the cell.
        encoding = "utf-8-sig" if suffix == ".csv" else "utf-8"
        with path.open(encoding=encoding, newline="") as f:
            return f.read()
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or type(exc).__name__})") from None


def _read_rows(path: Path) -> list[tuple[int, Any]]:
    suffix = _check_format(path)
    text = _read_text(path, suffix)
    if suffix == ".jsonl":
        return [
            (lineno, load_json_line(line, path, lineno))
            for lineno, line in enumerate(json_lines(text), start=1)
            if line.strip()
        ]
    return _read_csv(path, text)


def _read_csv(path: Path, text: str) -> list[tuple[int, Any]]:
    reader = csv.DictReader(io.StringIO(text, newline=""))
    rows: list[tuple[int, Any]] = []
    done = 0  # the last line of the last record read whole
    try:
        header = reader.fieldnames or []
        missing = [c for c in ("edge_id", "annotator", "label", "labeled_at") if c not in header]
        if missing:
            raise InputError(path, f"CSV header lacks {', '.join(missing)}", line=1)
        done = reader.line_num
        for row in reader:
            rows.append((done + 1, _csv_row(path, done + 1, row)))
            done = reader.line_num
    except csv.Error as exc:  # e.g. a cell over csv.field_size_limit() characters
        raise InputError(path, f"not CSV we read ({exc})", line=done + 1) from None
    return rows


def _csv_row(path: Path, lineno: int, row: dict[str | None, Any]) -> dict[str, Any]:
    """A CSV row as the JSONL row it was written from: cells unescaped, nested JSON parsed."""
    parsed: dict[str, Any] = {}
    for key, value in row.items():
        # A short row leaves None; a long one puts its extra cells under the key None.
        if key is None or value is None or value == "":
            continue
        value = unescape_cell(value)
        parsed[key] = load_json_line(value, path, lineno) if key in _NESTED else value
    return parsed


@dataclass(frozen=True)
class LabelFile:
    """A label file read and checked whole, ready to be written to a store.

    Attributes:
        path: The file.
        edges: Its rows' edges, in file order.
        records: Its rows' labels, in file order.
    """

    path: Path
    edges: list[Edge]
    records: list[LabelRecord]

    def write_to(self, store: LabelStore) -> tuple[int, int]:
        """Adds the edges and labels in one transaction; a newer label wins.

        Returns:
            (edges added, labels added or updated).
        """
        return store.import_all(self.edges, self.records)


def read_label_file(path: Path) -> LabelFile:
    """Reads and checks an exported label file, touching no store.

    Every row is checked: its schema, and that the studio can show its edge (the log is
    there, unchanged, and holds the scans). So a command can refuse a bad file before it
    makes or opens a workspace.

    Raises:
        InputError: A row is not an exported label (names the file, line and field), or
            the file holds none.
    """
    rows: list[tuple[int, Edge]] = []
    records: list[LabelRecord] = []
    for lineno, obj in _read_rows(path):
        edge, fields = parse_label_row(obj, path, lineno)
        rows.append((lineno, edge))
        records.append(
            LabelRecord(
                edge.edge_id, fields.annotator, fields.label, fields.note or "", fields.labeled_at
            )
        )
    if not records:
        raise InputError(path, "holds no labels")
    check_viewable(rows, path)
    return LabelFile(path, [edge for _, edge in rows], records)


def import_labels(store: LabelStore, path: Path) -> tuple[int, int]:
    """Adds a label file's edges and labels to the store; a newer label wins.

    Every row is checked first (``read_label_file``), then everything is written in one
    transaction: a bad row, or a failure while writing, changes nothing.

    Returns:
        (edges added, labels added or updated).

    Raises:
        InputError: A row is not an exported label (names the file, line and field).
    """
    return read_label_file(path).write_to(store)
