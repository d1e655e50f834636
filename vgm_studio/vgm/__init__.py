"""Stage 3: a matched scan pair → its Validation Grid Map (and pictures of it)."""

from vgm_studio.vgm.grid import VGMParams, grid_map, pair_map

__all__ = ["VGMParams", "grid_map", "pair_map"]
