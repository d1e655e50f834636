"""One edge as a PNG: the I/O around ``render.draw_pair``."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from vgm_studio.core import se2
from vgm_studio.errors import InputError
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge, read_edges
from vgm_studio.vgm.grid import pair_map
from vgm_studio.vgm.render import Caption, draw_pair


def edge_caption(edge: Edge, use_guess: bool) -> Caption:
    """A headline (label, inlier ratio) and the edge's figures and error vs reference below it.

    The error is of the pose drawn: the initial guess's with ``use_guess``, else the
    estimate's, so the header always describes the picture under it.
    """
    m = edge.match
    inliers = m.get("inlier_ratio")
    inlier_text = f"{100 * inliers:.0f}%" if isinstance(inliers, (int, float)) else "?"
    drawn = "initial guess" if use_guess else "match estimate"
    headline = f"{(edge.label or 'unlabelled').upper()}   inliers {inlier_text}"
    lines = [
        f"edge {edge.edge_id}  {edge.kind}  scans {edge.a} -> {edge.b}  (drawn: {drawn})",
        f"residual {1000 * (m.get('residual') or float('nan')):.1f} mm"
        f"   iterations {m.get('iterations', '?')}   converged {m.get('converged', '?')}"
        + (
            f"   kiss-icp moved {100 * m['kiss_moved']:.1f} cm"
            if isinstance(m.get("kiss_moved"), (int, float))
            else ""
        ),
    ]
    if edge.reference is not None:
        pose = edge.guess if use_guess else edge.estimate
        exy, eth = se2.pose_error(edge.reference, pose)
        error = f"{100 * exy:.1f} cm, {math.degrees(eth):.2f} deg"
        lines.append(f"{drawn} vs reference: {error}")
    check = m.get("reference_check")
    if isinstance(check, dict) and check.get("contradicted"):
        # Why a pair this far off its reference is not a failure.
        lines.append(
            f"scans contradict the reference (fit {check.get('fit_at_reference', 0):.2f} "
            f"there, {check.get('fit_from_reference', 0):.2f} at rest)"
        )
    return Caption(tuple(lines), headline=headline)


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
    ghost = None if edge.reference is None else np.asarray(edge.reference, dtype=np.float64)
    img = draw_pair(
        vgm,
        prev_pts,
        cur_pts,
        pose,
        resolution=resolution,
        caption=edge_caption(edge, use_guess),
        ghost_pose=ghost,
    )
    png.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(png), img):
        raise InputError(
            png, "cannot write the picture (is the suffix .png and the folder writable?)"
        )
    return img


def draw_edge(
    edges_file: Path,
    edge_id: str,
    png: Path,
    *,
    use_guess: bool = False,
    size: int = 400,
    resolution: float = 0.05,
    sigma: float = 0.02,
) -> None:
    """Draws the edge of ``edges_file`` whose id is or starts with ``edge_id`` to ``png``.

    Raises:
        InputError: No edge, or several, with that id.
    """
    edges = read_edges(edges_file)
    hits = [e for e in edges if e.edge_id.startswith(edge_id)]
    if len(hits) != 1:
        what = "no edge" if not hits else f"{len(hits)} edges"
        raise InputError(edges_file, f"{what} with id {edge_id!r}")
    edge_picture(
        hits[0],
        png,
        use_guess=use_guess,
        size=size,
        resolution=resolution,
        sigma=sigma,
        search_dirs=(edges_file.parent,),
    )
