"""The README's pair of heatmap pictures: a right and a wrong edge, raw cells beside spread.

    python benchmarks/heatmap_pictures.py [--workspace vgm-demo] [--out docs/images]

Draws the studio's 3D-view heatmap (cells only, +y up, 4 pixels a cell) of the demo's first
edge (sequential, 100 % inliers, 0.1 cm off its reference) and of a loop edge slid by one door
pitch (81 % inliers, 2.5 m off), each as the raw cells (V) beside the default, spread colours.
Makes the demo workspace first when it is missing (``vgm-studio demo --no-serve``).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from vgm_studio.labels import LabelStore
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.studio.view import PlacedPair, make_view
from vgm_studio.vgm.blend import BACKGROUND_RGB
from vgm_studio.vgm.grid import VGMParams

RIGHT, WRONG = "ad16e9210781f7dd", "0fac26820e5d32cd"
SCALE = 4


def _cells(placed: PlacedPair, colours: np.ndarray) -> np.ndarray:
    h, w = placed.heatmap_rgb.shape[:2]
    img = np.full((h, w, 3), BACKGROUND_RGB, dtype=np.uint8)
    cx, cy = placed.heatmap_centre
    cols = np.floor((placed.cells[:, 0] - cx) / placed.resolution + w / 2).astype(int)
    rows = np.floor((placed.cells[:, 1] - cy) / placed.resolution + h / 2).astype(int)
    img[rows, cols] = colours
    big = cv2.resize(img[::-1], (w * SCALE, h * SCALE), interpolation=cv2.INTER_NEAREST)
    return np.asarray(big, dtype=np.uint8)


def _titled(img: np.ndarray, title: str) -> np.ndarray:
    bar = np.full((28, img.shape[1], 3), 40, dtype=np.uint8)
    cv2.putText(bar, title, (8, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (235, 235, 235), 1)
    return np.vstack([bar, img])


def picture(store: LabelStore, edge_id: str, what: str) -> np.ndarray:
    """RGB: the edge's raw cells beside its spread colours, titled."""
    view = make_view(store.edge(edge_id), EdgeScans(), VGMParams())
    placed = view.estimate
    raw = _titled(_cells(placed, placed.raw_rgb), f"{what}: raw cells (V)")
    spread = _titled(_cells(placed, placed.cell_rgb), f"{what}: spread (default)")
    gap = np.full((raw.shape[0], 8, 3), 60, dtype=np.uint8)
    return np.hstack([raw, gap, spread])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workspace", type=Path, default=Path("vgm-demo"))
    parser.add_argument("--out", type=Path, default=Path("docs/images"))
    args = parser.parse_args()
    if not (args.workspace / "labels.sqlite").exists():
        demo = ["vgm-studio", "demo", "--no-serve", "--workspace", str(args.workspace)]
        subprocess.run(demo, check=True)
    store = LabelStore(args.workspace, create=False)
    args.out.mkdir(parents=True, exist_ok=True)
    for edge_id, name, what in (
        (RIGHT, "heatmap-right.png", "right match, 0.1 cm off"),
        (WRONG, "heatmap-wrong.png", "wrong match, 2.5 m off"),
    ):
        path = args.out / name
        cv2.imwrite(str(path), picture(store, edge_id, what)[..., ::-1])
        print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
