"""One edge as a PNG: the I/O around ``render.draw_pair``."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from vgm_studio.core import se2
from vgm_studio.errors import InputError
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.vgm.grid import pair_map
from vgm_studio.vgm.render import Caption, draw_pair


def edge_caption(edge: Edge, use_guess: bool) -> Caption:
    """Edge id, scans, kind, label and the matcher's figures, one line each."""
    m = edge.match
    lines = [
        f"edge {edge.edge_id}  {edge.kind}  scans {edge.a} -> {edge.b}  "
        f"({'initial guess' if use_guess else 'match estimate'})",
        f"label: {edge.label or 'unlabelled'}   inliers {m.get('inlier_ratio', float('nan')):.2f}"
        f"   residual {1000 * (m.get('residual') or float('nan')):.1f} mm"
        f"   iterations {m.get('iterations', '?')}",
    ]
    if edge.reference is not None:
        exy, eth = se2.pose_error(edge.reference, edge.estimate)
        lines.append(f"error vs reference: {100 * exy:.1f} cm, {math.degrees(eth):.2f} deg")
    return Caption(tuple(lines))


def edge_picture(
    edge: Edge,
    png: Path,
    *,
    use_guess: bool = False,
    size: int = 400,
    resolution: float = 0.05,
    sigma: float = 0.02,
    scans: EdgeScans | None = None,
    search_dirs: tuple[Path, ...] = (),
) -> np.ndarray:
    """Draws ``edge`` to ``png`` and returns the BGR image."""
    a, b = (scans or EdgeScans(search_dirs)).scans(edge)
    pose = np.asarray(edge.guess if use_guess else edge.estimate, dtype=np.float64)
    prev_pts, cur_pts = a.points(), b.points()
    vgm = pair_map(prev_pts, cur_pts, pose, size=size, resolution=resolution, sigma=sigma)
    img = draw_pair(
        vgm, prev_pts, cur_pts, pose, resolution=resolution, caption=edge_caption(edge, use_guess)
    )
    png.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(png), img):
        raise InputError(
            png, "cannot write the picture (is the suffix .png and the folder writable?)"
        )
    return img
