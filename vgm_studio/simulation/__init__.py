"""Corridor worlds → CARMEN logs with ground truth (``vgm-studio simulate``).

world.py       walls as the boundary of free-space rectangles, routes, people
presets.py     the named worlds (corridor, junctions, loops, repetitive, office, demo)
trajectory.py  route → true poses at the scan times
raycast.py     beams against walls and people
simulate.py    SimConfig → one log file
"""

from vgm_studio.simulation.presets import build_world, preset_names
from vgm_studio.simulation.simulate import SimConfig, SimPlan, plan, simulate

__all__ = ["SimConfig", "SimPlan", "build_world", "plan", "preset_names", "simulate"]
