"""A fleet's results: one Parquet table, a text summary and a grid of the after maps."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.atomic import atomic_path

TABLE_FILE = "fleet.parquet"
GRID_FILE = "after-maps.png"

# Column name → Arrow type name; a typed schema keeps a column's type when every row is null.
_COLUMNS: tuple[tuple[str, str], ...] = (
    ("name", "string"),
    ("status", "string"),
    ("error", "string"),
    ("log", "string"),
    ("reference", "string"),
    ("relations", "string"),
    ("log_sha256", "string"),
    ("key", "string"),
    ("candidates", "int64"),
    ("candidates_loop", "int64"),
    ("labelled_success", "int64"),
    ("labelled_failure", "int64"),
    ("model", "string"),
    ("model_threshold", "float64"),
    ("predicted_success", "int64"),
    ("predicted_failure", "int64"),
    ("accuracy", "float64"),
    ("f1", "float64"),
    ("scans", "int64"),
    ("keyframes", "int64"),
    ("edges_total", "int64"),
    ("edges_kept", "int64"),
    ("loops_total", "int64"),
    ("loops_kept", "int64"),
    ("loops_rejected", "int64"),
    ("loops_validator_kept", "int64"),
    ("loops_consistency_rejected", "int64"),
    ("loops_by_window", "int64"),
    ("loops_by_place", "int64"),
    ("loops_by_sweep", "int64"),
    ("odometry_trans_mean_m", "float64"),
    ("odometry_rot_mean_deg", "float64"),
    ("before_trans_mean_m", "float64"),
    ("before_rot_mean_deg", "float64"),
    ("after_trans_mean_m", "float64"),
    ("after_rot_mean_deg", "float64"),
    ("after_trans_std_m", "float64"),
    ("relations_n", "int64"),
    ("edges_file", "string"),
    ("slam_json", "string"),
    ("after_png", "string"),
    ("seconds", "float64"),
    ("attempts", "int64"),
    ("worker_pid", "int64"),
    ("model_loads", "int64"),
    ("skipped", "bool_"),
)


def write_table(path: Path, rows: list[dict[str, Any]]) -> Path:
    """Writes the rows as Parquet (every column of ``_COLUMNS``, null where a row lacks it)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = pa.schema([(name, getattr(pa, kind)()) for name, kind in _COLUMNS])
    table = pa.Table.from_pylist(
        [{name: row.get(name) for name, _ in _COLUMNS} for row in rows], schema=schema
    )
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)
    return path


def read_table(path: Path) -> list[dict[str, Any]]:
    """The rows of a fleet table, as dictionaries."""
    import pyarrow.parquet as pq

    rows: list[dict[str, Any]] = pq.read_table(path).to_pylist()
    return rows


def summary_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One line per log: status, loops kept, the after relation error, time; then totals."""
    width = max([len(r["name"]) for r in rows] + [4])
    lines = [
        f"{'log':<{width}}  {'status':<7} {'edges':>6} {'p≥cut':>6} {'loops kept':>11} "
        f"{'after m':>8} {'s':>6}"
    ]
    for r in rows:
        if r["status"] != "done":
            lines.append(f"{r['name']:<{width}}  {'failed':<7} {r['error']}")
            continue
        loops = f"{r['loops_kept']}/{r['loops_total']}"
        err = r.get("after_trans_mean_m")
        err_text = f"{err:.4f}" if err is not None else "–"
        state = "skipped" if r.get("skipped") else "done"
        lines.append(
            f"{r['name']:<{width}}  {state:<7} {r['candidates']:>6} {r['predicted_success']:>6} "
            f"{loops:>11} {err_text:>8} {r['seconds']:>6.0f}"
        )
    failed = sum(r["status"] != "done" for r in rows)
    skipped = sum(bool(r.get("skipped")) for r in rows)
    done = len(rows) - failed
    lines.append(f"{len(rows)} logs: {done} done ({skipped} skipped), {failed} failed")
    return lines


def write_grid(path: Path, rows: list[dict[str, Any]], tile: int = 360) -> Path:
    """The after maps of every log in a grid, each tile titled; a failed log's tile says so."""
    tiles = [_tile(r, tile) for r in rows]
    cols = min(4, len(tiles))
    nrows = math.ceil(len(tiles) / cols)
    blank = np.full_like(tiles[0], 255)
    tiles += [blank] * (nrows * cols - len(tiles))
    grid = np.vstack([np.hstack(tiles[i * cols : (i + 1) * cols]) for i in range(nrows)])
    ok, png = cv2.imencode(".png", grid)
    if not ok:
        raise OSError(f"OpenCV could not encode the {grid.shape} grid as PNG")
    with atomic_path(path) as tmp:
        tmp.write_bytes(png.tobytes())
    return path


def _tile(row: dict[str, Any], size: int) -> NDArray[np.uint8]:
    """A map scaled into a square with a title bar; a failed log gets its first words."""
    title_h = 28
    canvas = np.full((size + title_h, size, 3), 255, np.uint8)
    image = cv2.imread(row.get("after_png") or "") if row["status"] == "done" else None
    if image is not None:
        scale = min(size / image.shape[0], size / image.shape[1])
        h, w = max(1, int(image.shape[0] * scale)), max(1, int(image.shape[1] * scale))
        small = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
        y, x = title_h + (size - h) // 2, (size - w) // 2
        canvas[y : y + h, x : x + w] = small
        err = row.get("after_trans_mean_m")
        title = f"{row['name']}  loops {row['loops_kept']}/{row['loops_total']}"
        if err is not None:
            title += f"  {err:.3f} m"
    else:
        title = f"{row['name']}  FAILED"
        words = str(row.get("error") or "").split()
        for i in range(0, min(len(words), 40), 5):
            cv2.putText(canvas, " ".join(words[i : i + 5])[:48], (8, title_h + 30 + 4 * i),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 160), 1, cv2.LINE_AA)  # fmt: skip
    cv2.putText(canvas, title[:44], (6, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1,
                cv2.LINE_AA)  # fmt: skip
    cv2.rectangle(canvas, (0, 0), (size - 1, size + title_h - 1), (200, 200, 200), 1)
    return canvas
