"""Where a CARMEN log says its laser sits: ``PARAM robot_frontlaser_offset`` and its kin.

CARMEN writes its robot's parameters into the log before the first message that uses them:
``robot_frontlaser_offset`` (metres ahead of the robot's centre; −0.04 in several Freiburg
logs), ``robot_frontlaser_side_offset`` (to the left) and ``robot_frontlaser_angular_offset``
(radians), and the same for the rear laser. The pose fields of FLASER and RLASER are the
laser's pose; with the mount the scans and poses move to the robot's centre, the frame
Kümmerle et al.'s relations are given in. A value declared after the first scan is a change
of the robot mid-log, which one mount cannot follow: the value in force at the first scan is
the log's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vgm_studio.datasets.carmen_lines import LineParser
from vgm_studio.datasets.mount import LaserMount

_NAMES = {
    "front": (
        "robot_frontlaser_offset",
        "robot_frontlaser_side_offset",
        "robot_frontlaser_angular_offset",
    ),
    "rear": (
        "robot_rearlaser_offset",
        "robot_rearlaser_side_offset",
        "robot_rearlaser_angular_offset",
    ),
}
MOUNT_PARAMS = frozenset(_NAMES["front"] + _NAMES["rear"])


@dataclass
class DeclaredMount:
    """The mount PARAM lines declare, read up to the first scan.

    Attributes:
        values: Each parameter's last value before the first scan, with its line.
    """

    values: dict[str, tuple[float, int]] = field(default_factory=dict)

    def take(self, p: LineParser) -> None:
        """Reads ``PARAM name value …`` where ``name`` is a mount parameter.

        Raises:
            InputError: The value is not a finite number.
        """
        p.need(3, "a name and a value")
        self.values[p.tokens[1]] = (p.finite(2, f"{p.tokens[1]}'s value"), p.lineno)

    def mount(self, laser: str) -> tuple[LaserMount, str] | None:
        """The mount of the ``front`` or ``rear`` laser and where it was said; None where the
        log declares none of its parameters."""
        names = _NAMES[laser]
        found = [self.values.get(n) for n in names]
        if all(f is None for f in found):
            return None
        x, y, yaw = (0.0 if f is None else f[0] for f in found)
        said = ", ".join(
            f"{n} {f[0]:g} (line {f[1]})" for n, f in zip(names, found, strict=True) if f
        )
        return LaserMount(x, y, yaw), f"declared in the log: PARAM {said}"
