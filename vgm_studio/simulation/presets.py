"""Named worlds for ``vgm-studio simulate --preset``.

Each preset is a function returning a ``World``; the geometry is fixed, the seed only moves the
robot's wiggle, the noise and the people. Scans and metres are of the default config (0.1 m per
scan, the preset's own laps).

``corridor`` (~580 scans, 58 m)
    One straight featureless corridor, 60 m × 2 m: the degenerate case, where beams along the
    axis find nothing within 30 m.
``l-junction`` (~580 scans, 58 m)
    Two 30 m × 2 m corridors meeting at a right angle.
``t-junction`` (~790 scans, 75 m)
    A 40 m corridor with a 20 m side branch; the robot drives into the branch, turns in place at
    its dead end and comes back.
``loop`` (~1730 scans, 173 m)
    A rectangular corridor loop, 30 m × 14 m, 2.2 m wide, driven twice round.
``repetitive`` (~1810 scans, 181 m)
    A 36 m × 10 m loop, 2 m wide, lined with identical doors every 3 m on both walls, driven
    twice round.
``office`` (~1770 scans, 177 m)
    Corridors (2.4 m) round a 40 m × 20 m block with a 4 m pillared hall across it (four T
    junctions; the hall's ends open into bays), doors every 4 m, four side rooms; driven once as a
    figure of eight through the hall.
``demo`` (~380 scans, 38 m)
    A small loop (12 m × 5 m, 2 m wide) with doors every 2.5 m on both walls, 1.15 laps.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from vgm_studio.errors import InputError
from vgm_studio.simulation.world import (
    Point,
    Rect,
    World,
    corridor_rects,
    door_recesses,
    pillar_row,
    side_room,
    union_walls,
    walkway,
)

# People walk this far to one side of the centre line, clear of the robot's wiggle.
_LANE = 0.6


def _ring(width: float, height: float) -> list[Point]:
    """Corners of a rectangular loop starting and ending half way along its bottom side."""
    return [
        (width / 2, 0.0),
        (width, 0.0),
        (width, height),
        (0.0, height),
        (0.0, 0.0),
        (width / 2, 0.0),
    ]


def _sides(corners: list[Point]) -> list[tuple[Point, Point]]:
    """The legs of a ring from corner to corner (the split bottom side joined)."""
    pts = [corners[4], *corners[1:5]]
    return list(itertools.pairwise(pts))


def _world(
    name: str,
    rects: list[Rect],
    route: list[Point],
    *,
    closed: bool,
    laps: float,
    walkways: list[Rect],
    description: str,
    extra: NDArray[np.float64] | None = None,
) -> World:
    walls = union_walls(rects)
    if extra is not None:
        walls = np.concatenate([walls, extra])
    return World(
        name=name,
        walls=walls,
        route=np.array(route, dtype=np.float64),
        closed=closed,
        default_laps=laps,
        walkways=np.array(walkways, dtype=np.float64).reshape(-1, 4),
        description=description,
    )


def corridor() -> World:
    """60 m × 2 m straight corridor without features, driven end to end."""
    line = [(0.0, 0.0), (60.0, 0.0)]
    return _world(
        "corridor",
        corridor_rects(line, 2.0),
        [(1.0, 0.0), (59.0, 0.0)],
        closed=False,
        laps=1.0,
        walkways=[walkway(*line, offset=_LANE)],
        description="straight featureless corridor 60 m x 2 m",
    )


def l_junction() -> World:
    """Two 30 m × 2 m corridors meeting at a right angle."""
    line: list[Point] = [(0.0, 0.0), (30.0, 0.0), (30.0, 30.0)]
    return _world(
        "l-junction",
        corridor_rects(line, 2.0),
        [(1.0, 0.0), (30.0, 0.0), (30.0, 29.0)],
        closed=False,
        laps=1.0,
        walkways=[
            walkway(line[0], line[1], offset=_LANE),
            walkway(line[1], line[2], offset=-_LANE),
        ],
        description="L junction of two 30 m x 2 m corridors",
    )


def t_junction() -> World:
    """A 40 m corridor with a 20 m branch; the route goes up the branch and back."""
    bar: list[Point] = [(-20.0, 0.0), (20.0, 0.0)]
    stem: list[Point] = [(0.0, 0.0), (0.0, -20.0)]
    route: list[Point] = [(-19.0, 0.0), (0.0, 0.0), (0.0, -19.0), (0.0, 0.0), (19.0, 0.0)]
    return _world(
        "t-junction",
        corridor_rects(bar, 2.0) + corridor_rects(stem, 2.0),
        route,
        closed=False,
        laps=1.0,
        walkways=[
            walkway((-20.0, 0.0), (0.0, 0.0), offset=_LANE),
            walkway((0.0, 0.0), (20.0, 0.0), offset=-_LANE),
            walkway(*stem, offset=_LANE),
        ],
        description="T junction: 40 m x 2 m corridor with a 20 m branch",
    )


def loop() -> World:
    """Rectangular corridor loop 30 m × 14 m (centre line), 2.2 m wide, twice round."""
    ring = _ring(30.0, 14.0)
    return _world(
        "loop",
        corridor_rects(ring, 2.2),
        ring,
        closed=True,
        laps=2.0,
        walkways=[walkway(a, b, offset=-_LANE) for a, b in _sides(ring)],
        description="rectangular corridor loop 30 m x 14 m, 2.2 m wide",
    )


def repetitive() -> World:
    """36 m × 10 m loop, 2 m wide, with identical doors every 3 m on both walls."""
    ring = _ring(36.0, 10.0)
    rects = corridor_rects(ring, 2.0)
    for a, b in _sides(ring):
        rects += door_recesses(a, b, 2.0, pitch=3.0, margin=2.0)
    return _world(
        "repetitive",
        rects,
        ring,
        closed=True,
        laps=2.0,
        walkways=[walkway(a, b, offset=-_LANE) for a, b in _sides(ring)],
        description="36 m x 10 m corridor loop with identical doors every 3 m",
    )


def office() -> World:
    """Corridors round a 40 m × 20 m block, a pillared hall across it, doors and rooms."""
    ring = _ring(40.0, 20.0)
    width, hall_width = 2.4, 4.0
    hall: tuple[Point, Point] = ((20.0, 0.0), (20.0, 20.0))
    rects = corridor_rects(ring, width) + corridor_rects(list(hall), hall_width)
    _, east, north, west = _sides(ring)
    # Offices on the outer walls of the long corridors, split by the hall.
    for a, b in (((0.0, 0.0), (20.0, 0.0)), ((20.0, 0.0), (40.0, 0.0))):
        rects += door_recesses(a, b, width, pitch=4.0, margin=3.5, sides=(-1,))
    for a, b in (((40.0, 20.0), (20.0, 20.0)), ((20.0, 20.0), (0.0, 20.0))):
        rects += door_recesses(a, b, width, pitch=4.0, margin=3.5, sides=(-1,))
    # Rooms in the courtyards on either side of the hall.
    rects += side_room(*west, width, at=10.0, size=(6.0, 5.0), side=1)
    rects += side_room(*east, width, at=7.0, size=(5.0, 4.0), side=1)
    rects += side_room(*east, width, at=14.0, size=(4.0, 6.0), side=1)
    rects += side_room(*north, width, at=14.0, size=(5.0, 4.0), side=1)
    pillars = np.concatenate(
        [pillar_row(*hall, offset=side * 1.3, pitch=4.0, margin=3.0) for side in (1, -1)]
    )
    # A figure of eight: through the hall twice, along every corridor once.
    route: list[Point] = [
        (10.0, 0.0),
        (20.0, 0.0),
        (20.0, 20.0),
        (0.0, 20.0),
        (0.0, 0.0),
        (40.0, 0.0),
        (40.0, 20.0),
        (20.0, 20.0),
        (20.0, 0.0),
        (10.0, 0.0),
    ]
    walkways = [
        walkway(*hall, offset=0.7, margin=3.0),
        walkway((0.0, 0.0), (20.0, 0.0), offset=-_LANE),
        walkway((40.0, 20.0), (20.0, 20.0), offset=-_LANE),
        walkway(*west, offset=_LANE),
        walkway(*east, offset=-_LANE),
    ]
    return _world(
        "office",
        rects,
        route,
        closed=True,
        laps=1.0,
        walkways=walkways,
        extra=pillars,
        description="office: corridors round a 40 m x 20 m block, pillared hall, "
        "doors every 4 m, side rooms",
    )


def demo() -> World:
    """Small loop 12 m × 5 m with doors every 2.5 m, a little over one lap (~380 scans)."""
    ring = _ring(12.0, 5.0)
    rects = corridor_rects(ring, 2.0)
    south, _, north, _ = _sides(ring)
    for a, b in (south, north):
        rects += door_recesses(a, b, 2.0, pitch=2.5, margin=1.8)
    return _world(
        "demo",
        rects,
        ring,
        closed=True,
        laps=1.15,
        walkways=[
            walkway(*south, offset=-_LANE, margin=2.0),
            walkway(*north, offset=-_LANE, margin=2.0),
        ],
        description="demo: 12 m x 5 m corridor loop with identical doors every 2.5 m",
    )


PRESETS: dict[str, Callable[[], World]] = {
    "corridor": corridor,
    "l-junction": l_junction,
    "t-junction": t_junction,
    "loop": loop,
    "repetitive": repetitive,
    "office": office,
    "demo": demo,
}


def preset_names() -> tuple[str, ...]:
    """The preset names, in the order the help lists them."""
    return tuple(PRESETS)


def build_world(name: str) -> World:
    """Returns the named preset's world.

    Raises:
        InputError: No preset has that name.
    """
    builder = PRESETS.get(name)
    if builder is None:
        raise InputError(None, f"unknown preset {name!r} (choose from: {', '.join(PRESETS)})")
    return builder()
