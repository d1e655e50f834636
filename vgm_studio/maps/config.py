"""Typed configuration of the occupancy grid maps."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MapConfig:
    """Occupancy grid maps.

    Attributes:
        resolution: Cell edge, metres.
        max_range: Beams longer than this are left out, metres.
        log_odds_hit: Log-odds added to the cell a beam ends in.
        log_odds_miss: Log-odds added to each cell a beam crosses.
        clamp: Log-odds are kept within ±this, so a map can still change its mind.
        max_cells: A map larger than this many cells on a side is drawn with coarser cells
            so that it fits (a large building still gets a picture, at a resolution that
            keeps it within memory)…
        max_resolution: …up to this cell edge, metres; past it the map is refused (a broken
            graph can scatter scans over kilometres).
    """

    resolution: float = 0.05
    max_range: float = 30.0
    log_odds_hit: float = 0.85
    log_odds_miss: float = -0.4
    clamp: float = 5.0
    max_cells: int = 6000
    max_resolution: float = 0.5
