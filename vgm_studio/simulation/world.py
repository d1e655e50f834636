"""Simulated worlds: wall segments, the robot's route and people walking about.

Free space is drawn as axis-aligned rectangles (corridors, door recesses, rooms, the doorways
into them) and the walls are the boundary of their union. Junctions, recesses and doorways so
come out right without placing a single wall segment by hand. Pillars are solid boxes added on
top. Walls have no thickness: a room beside a corridor must leave a gap (the wall thickness)
that only its doorway bridges.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

Point = tuple[float, float]
Rect = tuple[float, float, float, float]
"""Free space ``(xmin, ymin, xmax, ymax)``."""

# Coordinates are rounded to this many decimals before the union so that rectangles computed by
# different arithmetic still share edges exactly; _PROBE must stay far above the rounding.
_DECIMALS = 6
_PROBE = 1e-4


def _no_segments() -> NDArray[np.float64]:
    return np.zeros((0, 4), dtype=np.float64)


@dataclass(frozen=True)
class Person:
    """Someone walking back and forth along a straight line at constant speed.

    Attributes:
        start: One end of the walk (x, y).
        end: The other end.
        speed: Walking speed in m/s.
        phase: Position in the walk cycle at t = 0, in [0, 2): 0 at ``start``, 1 at ``end``.
        radius: The person as a circle at laser height, in metres.
    """

    start: Point
    end: Point
    speed: float = 1.0
    phase: float = 0.0
    radius: float = 0.2

    def position(self, t: float) -> NDArray[np.float64]:
        """Returns the (x, y) centre at time ``t`` seconds."""
        a, b = np.asarray(self.start, dtype=np.float64), np.asarray(self.end, dtype=np.float64)
        length = math.hypot(*(b - a))
        if length == 0.0:
            return a
        u = (self.phase + t * self.speed / length) % 2.0
        return a + (u if u <= 1.0 else 2.0 - u) * (b - a)


@dataclass(frozen=True, eq=False)
class World:
    """A 2D world to ray cast, with the route the robot follows through it.

    Attributes:
        name: The preset name.
        walls: (M, 4) wall segments ``x1 y1 x2 y2`` in metres.
        route: (K, 2) waypoints on corridor centre lines, in driving order.
        closed: The route is a loop (last waypoint = first): laps go round it again. An open
            route is driven back and forth instead, turning in place at its ends.
        default_laps: Laps (or passes of an open route) when the config does not say.
        walkways: (W, 4) lines people may walk along, clear of the robot's route.
        people: The people in the world; see ``with_people``.
        description: One line for log headers.
    """

    name: str
    walls: NDArray[np.float64]
    route: NDArray[np.float64]
    closed: bool = False
    default_laps: float = 1.0
    walkways: NDArray[np.float64] = field(default_factory=_no_segments)
    people: tuple[Person, ...] = ()
    description: str = ""

    def people_at(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Returns the people's (P, 2) centres and (P,) radii at time ``t``."""
        if not self.people:
            return np.zeros((0, 2)), np.zeros(0)
        centres = np.array([p.position(t) for p in self.people])
        return centres, np.array([p.radius for p in self.people])

    def with_people(self, count: int, rng: np.random.Generator) -> World:
        """Returns this world with ``count`` people spread over the walkways in turn.

        Each walks at 0.6–1.3 m/s and starts at a random point of its walk.
        """
        if count > 0 and len(self.walkways) == 0:
            raise ValueError(f"world {self.name!r} has no walkways for people")
        people = []
        for k in range(count):
            x1, y1, x2, y2 = (float(v) for v in self.walkways[k % len(self.walkways)])
            speed, phase = float(rng.uniform(0.6, 1.3)), float(rng.uniform(0.0, 2.0))
            people.append(Person((x1, y1), (x2, y2), speed=speed, phase=phase))
        return replace(self, people=tuple(people))


def _frame(a: Point, b: Point) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Unit direction a→b, its left normal and the length; the line must be axis-aligned."""
    pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    delta = pb - pa
    length = float(np.hypot(*delta))
    if length == 0.0 or min(abs(delta[0]), abs(delta[1])) > 1e-9:
        raise ValueError(f"corridor {a}→{b} must be axis-aligned and non-empty")
    d = delta / length
    return d, np.array([-d[1], d[0]]), length


def strip(a: Point, b: Point, s0: float, s1: float, o0: float, o1: float) -> Rect:
    """Returns the rectangle ``s0..s1`` along the line a→b and ``o0..o1`` to its left."""
    d, n, _ = _frame(a, b)
    corners = np.array([np.asarray(a) + s * d + o * n for s in (s0, s1) for o in (o0, o1)])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def corridor_rects(centreline: Sequence[Point], width: float) -> list[Rect]:
    """Returns the free space of a corridor along an axis-aligned polyline.

    Each leg runs ``width / 2`` past its ends so that corners fill in and dead ends have a wall
    half a corridor width beyond the last waypoint.
    """
    rects = []
    for a, b in itertools.pairwise(centreline):
        _, _, length = _frame(a, b)
        rects.append(strip(a, b, -width / 2, length + width / 2, -width / 2, width / 2))
    return rects


def _pitch_positions(length: float, pitch: float, margin: float) -> NDArray[np.float64]:
    # Centred on the leg so that both junctions get the same clearance.
    usable = length - 2 * margin
    if usable < 0:
        return np.zeros(0)
    count = math.floor(usable / pitch + 1e-9) + 1
    first = (length - (count - 1) * pitch) / 2
    return first + pitch * np.arange(count, dtype=np.float64)


def door_recesses(
    a: Point,
    b: Point,
    corridor_width: float,
    *,
    pitch: float,
    door_width: float = 0.9,
    depth: float = 0.25,
    margin: float = 2.0,
    sides: Sequence[int] = (1, -1),
) -> list[Rect]:
    """Returns identical door recesses every ``pitch`` metres along the corridor a→b.

    Args:
        a: Start of the corridor's centre line.
        b: End of it.
        corridor_width: The corridor's width.
        pitch: Distance between door centres.
        door_width: Width of each recess along the corridor.
        depth: How far each recess goes into the wall.
        margin: No doors closer than this to a or b (junctions).
        sides: 1 for the left wall (seen from a towards b), -1 for the right.
    """
    _, _, length = _frame(a, b)
    half = corridor_width / 2
    return [
        strip(a, b, s - door_width / 2, s + door_width / 2, side * half, side * (half + depth))
        for s in _pitch_positions(length, pitch, margin)
        for side in sides
    ]


def side_room(
    a: Point,
    b: Point,
    corridor_width: float,
    *,
    at: float,
    size: tuple[float, float],
    side: int = 1,
    door_width: float = 0.9,
    wall: float = 0.15,
) -> list[Rect]:
    """Returns a room beside the corridor a→b and the doorway into it.

    Args:
        a: Start of the corridor's centre line.
        b: End of it.
        corridor_width: The corridor's width.
        at: Distance from a of the room's and the door's centre.
        size: The room's (length along the corridor, depth away from it).
        side: 1 for the left of a→b, -1 for the right.
        door_width: Width of the doorway.
        wall: Thickness of the wall between corridor and room.
    """
    half, (length, depth) = corridor_width / 2, size
    door = strip(a, b, at - door_width / 2, at + door_width / 2, side * half, side * (half + wall))
    room = strip(
        a, b, at - length / 2, at + length / 2, side * (half + wall), side * (half + wall + depth)
    )
    return [door, room]


def box_walls(rect: Rect) -> NDArray[np.float64]:
    """Returns the four sides of a solid box as (4, 4) segments."""
    x0, y0, x1, y1 = rect
    return np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]])


def pillar_row(
    a: Point, b: Point, *, offset: float, pitch: float, size: float = 0.4, margin: float = 2.0
) -> NDArray[np.float64]:
    """Returns square pillars every ``pitch`` metres, ``offset`` left of the line a→b."""
    _, _, length = _frame(a, b)
    boxes = [
        box_walls(strip(a, b, s - size / 2, s + size / 2, offset - size / 2, offset + size / 2))
        for s in _pitch_positions(length, pitch, margin)
    ]
    return np.concatenate(boxes) if boxes else _no_segments()


def walkway(a: Point, b: Point, *, offset: float, margin: float = 2.5) -> Rect:
    """Returns a line ``offset`` left of a→b, ``margin`` short of both ends, for people."""
    d, n, length = _frame(a, b)
    p = np.asarray(a) + margin * d + offset * n
    q = np.asarray(a) + (length - margin) * d + offset * n
    return (float(p[0]), float(p[1]), float(q[0]), float(q[1]))


def _inside(
    rects: NDArray[np.float64], px: NDArray[np.float64], py: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """Whether each probe point lies strictly inside any rectangle."""
    x, y = px[:, None], py[:, None]
    inside: NDArray[np.bool_] = np.any(
        (rects[:, 0] < x) & (x < rects[:, 2]) & (rects[:, 1] < y) & (y < rects[:, 3]), axis=1
    )
    return inside


def union_walls(rects: Sequence[Rect] | ArrayLike) -> NDArray[np.float64]:
    """Returns the boundary of a union of axis-aligned rectangles as (M, 4) wall segments.

    Every rectangle edge is cut at all other rectangles' coordinates; a piece is a wall where
    the space just outside it is free in no rectangle. Collinear touching pieces are merged, so
    a corridor wall is one segment from junction to junction (or door to door).
    """
    r = np.round(np.asarray(rects, dtype=np.float64).reshape(-1, 4), _DECIMALS)
    cuts = (
        np.unique(np.concatenate([r[:, 0], r[:, 2]])),
        np.unique(np.concatenate([r[:, 1], r[:, 3]])),
    )
    # key: (axis the edge runs along, its fixed coordinate, outward sign) → pieces (lo, hi)
    pieces: dict[tuple[int, float, int], set[tuple[float, float]]] = {}
    for rect in r:
        for axis in (0, 1):
            lo, hi = rect[axis], rect[axis + 2]
            inner = cuts[axis][(cuts[axis] > lo) & (cuts[axis] < hi)]
            ends = np.concatenate([[lo], inner, [hi]])
            mids = (ends[:-1] + ends[1:]) / 2
            for sign, fixed in ((-1, rect[1 - axis]), (1, rect[3 - axis])):
                probe = np.full_like(mids, fixed + sign * _PROBE)
                outside_free = _inside(r, mids, probe) if axis == 0 else _inside(r, probe, mids)
                key = (axis, float(fixed), sign)
                for k in np.flatnonzero(~outside_free):
                    pieces.setdefault(key, set()).add((float(ends[k]), float(ends[k + 1])))
    segments = []
    for (axis, fixed, _sign), spans in sorted(pieces.items()):
        merged: list[list[float]] = []
        for lo, hi in sorted(spans):
            if merged and lo <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], hi)
            else:
                merged.append([lo, hi])
        for lo, hi in merged:
            segments.append([lo, fixed, hi, fixed] if axis == 0 else [fixed, lo, fixed, hi])
    return np.array(segments, dtype=np.float64).reshape(-1, 4)


def segment_distances(points: ArrayLike, walls: NDArray[np.float64]) -> NDArray[np.float64]:
    """Returns each (N, 2) point's distance to the nearest of the (M, 4) segments."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    a, e = walls[:, :2], walls[:, 2:] - walls[:, :2]
    rel = p[:, None, :] - a[None, :, :]
    length2 = np.maximum(np.sum(e * e, axis=1), 1e-300)
    u = np.clip(np.sum(rel * e[None], axis=2) / length2, 0.0, 1.0)
    gap = rel - u[..., None] * e[None]
    distance: NDArray[np.float64] = np.sqrt(np.min(np.sum(gap * gap, axis=2), axis=1))
    return distance
