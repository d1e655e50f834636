"""Small real files for the untrusted-input tests: a CARMEN log, its edges, exported labels."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from vgm_studio.core.hashing import content_hash
from vgm_studio.labels import LabelStore
from vgm_studio.labels.transfer import export_labels, import_labels
from vgm_studio.matching.edges import Edge, edge_id

SCANS = 6


def write_log(folder: Path, name: str = "tiny.log") -> Path:
    """A CARMEN log of ``SCANS`` FLASER scans of five readings, with odometry."""
    lines = [
        f"FLASER 5 1.0 1.5 2.0 1.5 1.0 {0.1 * i:.1f} 0 0 {0.1 * i:.1f} 0 0 {i}.5 host {i}.5"
        for i in range(SCANS)
    ]
    path = folder / name
    path.write_text("\n".join(lines) + "\n")
    return path


def make_edges(log: Path, count: int = 3) -> list[Edge]:
    """Edges between consecutive scans of ``log``, as ``candidates`` would write them."""
    sha = content_hash(log)
    edges = []
    for a in range(count):
        estimate = [0.1, 0.0, 0.01 * a]
        edges.append(
            Edge(
                edge_id=edge_id(sha, a, a + 1, estimate),
                log_path=str(log.resolve()),
                log_sha256=sha,
                a=a,
                b=a + 1,
                timestamp_a=a + 0.5,
                timestamp_b=a + 1.5,
                kind="sequential",
                guess=[0.1, 0.0, 0.0],
                estimate=estimate,
                match={"iterations": 3, "converged": True, "inlier_ratio": 0.9},
                reference=[0.1, 0.0, 0.0],
                label="success",
                params={"read": {"poses": "auto"}},
            )
        )
    return edges


def label_row(edge: Edge, **kw: Any) -> dict[str, Any]:
    """An exported label row of ``edge`` (the JSONL schema of ``vgm-studio export``)."""
    row = edge.to_json()
    row["reference_label"] = row.pop("label")
    row.update(label="success", annotator="ana", labeled_at="2026-01-01T12:00:00+00:00", note="")
    row.update(kw)
    return row


def write_jsonl(path: Path, rows: list[Any]) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def seed_files(folder: Path) -> dict[str, Path]:
    """Valid files of every kind the fuzzers mutate, with a real log behind the edges and
    labels: the log, edges, labels as JSON lines and as CSV, and a relations file."""
    log = write_log(folder)
    edges = make_edges(log)
    (folder / "edges.jsonl").write_text("".join(json.dumps(e.to_json()) + "\n" for e in edges))
    rows = [label_row(e, annotator=name) for e in edges for name in ("ana", "ben")]
    (folder / "labels.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    store = LabelStore(folder / "export")
    import_labels(store, folder / "labels.jsonl")
    export_labels(store, folder / "labels.csv")
    store.close()
    (folder / "r.relations").write_text("0.5 1.5 0.1 0 0 0 0 0.01\n1.5 2.5 0.1 0 0 0 0 0\n")
    return {
        "log": log,
        "edges": folder / "edges.jsonl",
        "labels.jsonl": folder / "labels.jsonl",
        "labels.csv": folder / "labels.csv",
        "relations": folder / "r.relations",
    }
