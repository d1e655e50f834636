"""The point-to-line refinement's loops, compiled (numba).

In numpy each Gauss-Newton iteration was a k-d tree query and a dozen array passes over a
scan's ~200 points, each pass costing more in numpy's per-call overhead than in arithmetic:
0.9 ms a refinement on Intel's scans, a quarter of a SLAM run's CPU time. Here an iteration
is one pass: each point finds its nearest target point through a grid of cells (every point
within the gate lies in the cells the gate's square covers, so the nearest found is the
nearest there is) and adds its residual to the normal equations. The kernels let go of the
GIL, so the threads that match loop candidates refine at once.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core.compiled import kernel

# Radians are scaled to metres at this lever arm when comparing curvatures across x, y, θ.
LEVER = 5.0


@kernel
def _nearest(x: float, y: float, cells: Any, frame: Any, reach: int, bound2: float) -> int:
    """The target point nearest (x, y) closer than √bound2 (ties: the lowest index), or -1.

    ``cells`` is (points sorted by cell, their indices, sorted cell keys, each key's first
    point and one past the last); ``frame`` the grid's (origin x, origin y, cell, nx, ny),
    and the neighbours a normal is fitted to.
    """
    points, index, keys, starts = cells
    ox, oy, size = frame[0], frame[1], frame[2]
    nx, ny = int(frame[3]), int(frame[4])
    if not (np.isfinite(x) and np.isfinite(y)):
        return -1
    fx, fy = np.floor((x - ox) / size), np.floor((y - oy) / size)
    if fx < -reach or fx > nx + reach or fy < -reach or fy > ny + reach:
        return -1
    cx, cy = int(fx), int(fy)
    best, best_d2 = -1, bound2
    for i in range(max(cx - reach, 0), min(cx + reach, nx - 1) + 1):
        lo, hi = i * ny + max(cy - reach, 0), i * ny + min(cy + reach, ny - 1)
        if lo > hi:
            continue
        # A row's cells are consecutive keys: one search finds them all.
        k = np.searchsorted(keys, lo)
        while k < keys.shape[0] and keys[k] <= hi:
            for p in range(starts[k], starts[k + 1]):
                dx, dy = points[p, 0] - x, points[p, 1] - y
                d2 = dx * dx + dy * dy
                if d2 < best_d2 or (d2 == best_d2 and best >= 0 and index[p] < index[best]):
                    best, best_d2 = p, d2
            k += 1
    return best


@kernel
def _offer(p: int, d2: float, index: Any, best_i: Any, best_d: Any, count: int) -> int:
    """Puts point ``p`` at squared distance ``d2`` into the k nearest so far (``best_i``,
    ``best_d``: indices and squared distances, nearest first; ties: the lower index);
    returns how many it holds."""
    k = best_d.shape[0]
    # Written as one condition each: numba compiles an early ``break`` here three times slower.
    if count == k and (
        d2 > best_d[k - 1] or (d2 == best_d[k - 1] and index[p] > index[best_i[k - 1]])
    ):
        return count
    r = min(count, k - 1)
    while r > 0 and (
        best_d[r - 1] > d2 or (best_d[r - 1] == d2 and index[best_i[r - 1]] > index[p])
    ):
        best_d[r], best_i[r] = best_d[r - 1], best_i[r - 1]
        r -= 1
    best_d[r], best_i[r] = d2, p
    return int(min(count + 1, k))


@kernel
def _offer_cells(
    query: Any, row: Any, cells: Any, ny: int, best_i: Any, best_d: Any, count: int
) -> int:
    """Offers every point of the cells ``row`` = (i, j0, j1) to the k nearest ``query``."""
    points, index, keys, starts = cells
    x, y = query
    i, j0, j1 = row
    k = np.searchsorted(keys, i * ny + j0)
    while k < keys.shape[0] and keys[k] <= i * ny + j1:
        for p in range(starts[k], starts[k + 1]):
            dx, dy = points[p, 0] - x, points[p, 1] - y
            count = _offer(p, dx * dx + dy * dy, index, best_i, best_d, count)
        k += 1
    return count


@kernel
def line_normals(cells: Any, frame: Any, normals: Any) -> None:
    """Fills in every normal of ``normals`` still unknown (NaN); see ``_line_normal``."""
    best_i, best_d = _scratch(cells, frame)
    for p in range(normals.shape[0]):
        _normal_at(p, cells, normals, frame, best_i, best_d)


@kernel
def _scratch(cells: Any, frame: Any) -> Any:
    """Room for a point's k nearest (``_line_normal``): indices and squared distances."""
    k = min(int(frame[5]), cells[0].shape[0])
    return np.empty(k, np.int64), np.empty(k)


@kernel
def _normal_at(p: int, cells: Any, normals: Any, frame: Any, best_i: Any, best_d: Any) -> Any:
    """Point ``p``'s normal (in ``cells``' order), computed on first use.

    A refinement meets only the target points nearest its source's: a submap's normals,
    all computed up front, were 1.0 µs a point and 4.4 M points on Intel. NaN marks one not
    yet known; threads refining on one target at once may each compute a normal, and write
    the same bits (an aligned float is written whole, and a half-written pair still holds a
    NaN, so it is computed again).
    """
    n0, n1 = normals[p, 0], normals[p, 1]
    if np.isnan(n0) or np.isnan(n1):
        n0, n1 = _line_normal(p, cells, frame, best_i, best_d)
        normals[p, 0], normals[p, 1] = n0, n1
    return n0, n1


@kernel
def _line_normal(p: int, cells: Any, frame: Any, best_i: Any, best_d: Any) -> Any:
    """Point ``p``'s local line normal (``cells``' order): the normal to the principal axis of
    its ``frame[5]`` nearest points (itself included).

    The cells are searched in square rings around the point's own until the k-th nearest is
    nearer than any point beyond the ring can be.
    """
    points = cells[0]
    size, nx, ny = frame[2], int(frame[3]), int(frame[4])
    k = best_d.shape[0]
    x, y = points[p, 0], points[p, 1]
    cx, cy = int(np.floor((x - frame[0]) / size)), int(np.floor((y - frame[1]) / size))
    count, ring = 0, 0
    while True:
        for i in range(max(cx - ring, 0), min(cx + ring, nx - 1) + 1):
            # The ring's whole first and last rows; of the rows between, its two sides.
            if abs(i - cx) == ring:
                j0, j1 = max(cy - ring, 0), min(cy + ring, ny - 1)
                if j0 <= j1:
                    row = (i, j0, j1)
                    count = _offer_cells((x, y), row, cells, ny, best_i, best_d, count)
            else:
                for j in (cy - ring, cy + ring):
                    if 0 <= j < ny:
                        row = (i, j, j)
                        count = _offer_cells((x, y), row, cells, ny, best_i, best_d, count)
        # A point beyond this ring lies outside its square of cells, so at least as far
        # as the square's nearest side: ``ring`` cells and the way to the own cell's edge
        # (where a point's k nearest are near it, the own cell alone can hold them).
        left, bottom = frame[0] + (cx - ring) * size, frame[1] + (cy - ring) * size
        reach = min(x - left, y - bottom, left + (2 * ring + 1) * size - x)
        reach = min(reach, bottom + (2 * ring + 1) * size - y)
        if count == k and best_d[k - 1] <= reach * reach:
            break
        if ring > nx and ring > ny:
            break
        ring += 1
    mx, my = 0.0, 0.0
    for q in range(k):
        mx += points[best_i[q], 0]
        my += points[best_i[q], 1]
    mx, my = mx / k, my / k
    sxx, syy, sxy = 0.0, 0.0, 0.0
    for q in range(k):
        dx, dy = points[best_i[q], 0] - mx, points[best_i[q], 1] - my
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    # The local line runs along the principal axis; its normal is perpendicular to it.
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return -np.sin(phi), np.cos(phi)


@kernel
def _normal_equations(
    cells: Any,
    normals: Any,
    frame: Any,
    source: Any,
    pose: Any,
    max_distance: float,
    inlier_distance: float,
    huber: bool,
) -> Any:
    """(H, g, paired, inliers, Σr² of inliers) of the point-to-line residuals at ``pose``:
    Huber-weighted over every paired point where ``huber``, else unweighted over the inliers
    (the covariance's information)."""
    points = cells[0]
    reach = int(np.ceil(max_distance / frame[2]))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    h, g = np.zeros((3, 3)), np.zeros(3)
    jac = np.empty(3)
    best_i, best_d = _scratch(cells, frame)
    paired, inliers, sum2 = 0, 0, 0.0
    for i in range(source.shape[0]):
        px, py = source[i, 0], source[i, 1]
        mx, my = c * px - s * py + pose[0], s * px + c * py + pose[1]
        q = _nearest(mx, my, cells, frame, reach, max_distance * max_distance)
        if q < 0:
            continue
        paired += 1
        n0, n1 = _normal_at(q, cells, normals, frame, best_i, best_d)
        r = n0 * (mx - points[q, 0]) + n1 * (my - points[q, 1])
        inlier = abs(r) < inlier_distance
        if inlier:
            inliers += 1
            sum2 += r * r
        if huber:
            w = min(1.0, inlier_distance / max(abs(r), 1e-12))
        elif inlier:
            w = 1.0
        else:
            continue
        # d(moved)/dθ is (moved − t) turned by 90°.
        jac[0], jac[1] = n0, n1
        jac[2] = n1 * (mx - pose[0]) - n0 * (my - pose[1])
        for a in range(3):
            g[a] += w * r * jac[a]
            for b in range(3):
                h[a, b] += w * jac[a] * jac[b]
    return h, g, paired, inliers, sum2


@kernel
def _constrained_step(h: Any, g: Any, degeneracy: float) -> Any:
    """Gauss-Newton step restricted to well-constrained directions (solution remapping);
    (step, True), or (zeros, False) where H has no curvature."""
    scale = np.array([1.0, 1.0, 1.0 / LEVER])
    hs = h * np.outer(scale, scale)
    gs = g * scale
    step = np.zeros(3)
    if not (np.all(np.isfinite(hs)) and np.all(np.isfinite(gs))):
        return step, False
    lam, vec = np.linalg.eigh(hs)
    if lam[2] <= 0:
        return step, False
    for k in range(3):
        if lam[k] > degeneracy * lam[2]:
            along = (vec[0, k] * gs[0] + vec[1, k] * gs[1] + vec[2, k] * gs[2]) / lam[k]
            step -= vec[:, k] * along
    return step * scale, True


@kernel
def gauss_newton(
    cells: Any,
    normals: Any,
    frame: Any,
    source: Any,
    guess: Any,
    settings: Any,
) -> Any:
    """(pose, iterations, converged) from ``guess``; ``settings`` is (max iterations, max
    distance, inlier distance, tolerance, degeneracy)."""
    max_iterations, max_distance, inlier_distance = int(settings[0]), settings[1], settings[2]
    tolerance, degeneracy = settings[3], settings[4]
    pose = guess.copy()
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 - the count is returned
        h, g, paired, _, _ = _normal_equations(
            cells, normals, frame, source, pose, max_distance, inlier_distance, True
        )
        if paired < 3:
            break
        delta, ok = _constrained_step(h, g, degeneracy)
        if not ok:
            break
        pose += delta
        pose[2] = np.pi - np.mod(np.pi - pose[2], 2.0 * np.pi)
        if np.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2) < tolerance:
            converged = True
            break
    return pose, it, converged


def figures(
    cells: Any,
    normals: NDArray[np.float64],
    frame: NDArray[np.float64],
    source: NDArray[np.float64],
    pose: NDArray[np.float64],
    max_distance: float,
    inlier_distance: float,
) -> tuple[NDArray[np.float64], int, int, float]:
    """(JᵀJ of the inliers, paired, inliers, Σr² of the inliers) at ``pose``."""
    h, _, paired, inliers, sum2 = _normal_equations(
        cells, normals, frame, source, pose, max_distance, inlier_distance, False
    )
    return h, int(paired), int(inliers), float(sum2)
