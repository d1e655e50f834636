"""The robot's true motion: a route's waypoints turned into timed poses.

The robot drives the straight legs at constant speed with a gentle lateral wiggle, rounds
corners on circular arcs with the heading along the path, and turns in place where the route
doubles back. Poses are sampled at a fixed scan period, so turning in place yields scans too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core.se2 import wrap_angle

# Corners are rounded with this radius where the legs are long enough.
CORNER_RADIUS = 0.8
# Turns sharper than this are driven as stop, turn in place, go.
MAX_ARC_TURN = math.radians(150.0)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """True poses (x, y, θ) of the robot at its scan times."""

    times: NDArray[np.float64]
    poses: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.times.shape[0])

    def travelled(self) -> float:
        """Path length in metres."""
        return float(np.sum(np.hypot(*np.diff(self.poses[:, :2], axis=0).T)))


class _Piece(Protocol):
    @property
    def duration(self) -> float: ...

    def poses(self, tau: NDArray[np.float64]) -> NDArray[np.float64]: ...


@dataclass(frozen=True)
class _Line:
    start: NDArray[np.float64]
    heading: float
    length: float
    speed: float
    amplitude: float
    wavelength: float
    phase: float

    @property
    def duration(self) -> float:
        return self.length / self.speed

    def _offset(self, s: NDArray[np.float64]) -> NDArray[np.float64]:
        # The envelope takes the wiggle (and its slope) to zero at both ends so that the legs
        # join the corner arcs without a jump in position or heading.
        ramp = min(1.5, self.length / 2)
        x = np.clip(np.minimum(s, self.length - s) / ramp, 0.0, 1.0)
        envelope = x * x * (3.0 - 2.0 * x)
        return self.amplitude * envelope * np.sin(2 * np.pi * s / self.wavelength + self.phase)

    def poses(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        s = self.speed * tau
        h = 1e-4
        w = self._offset(s)
        slope = (self._offset(s + h) - self._offset(s - h)) / (2 * h)
        c, n = np.cos(self.heading), np.sin(self.heading)
        x = self.start[0] + s * c - w * n
        y = self.start[1] + s * n + w * c
        return np.stack([x, y, self.heading + np.arctan(slope)], axis=1)


@dataclass(frozen=True)
class _Arc:
    centre: NDArray[np.float64]
    radius: float
    heading: float  # at the start
    sweep: float  # signed, radians
    speed: float

    @property
    def duration(self) -> float:
        return self.radius * abs(self.sweep) / self.speed

    def poses(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        turned = np.sign(self.sweep) * self.speed * tau / self.radius
        heading = self.heading + turned
        # The centre lies to the inside of the turn, so the robot sits at heading ∓ 90°.
        spoke = heading - np.sign(self.sweep) * np.pi / 2
        x = self.centre[0] + self.radius * np.cos(spoke)
        y = self.centre[1] + self.radius * np.sin(spoke)
        return np.stack([x, y, heading], axis=1)


@dataclass(frozen=True)
class _Turn:
    point: NDArray[np.float64]
    heading: float
    sweep: float
    rate: float

    @property
    def duration(self) -> float:
        return abs(self.sweep) / self.rate

    def poses(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        heading = self.heading + np.sign(self.sweep) * self.rate * tau
        return np.stack(
            [np.full_like(tau, self.point[0]), np.full_like(tau, self.point[1]), heading], axis=1
        )


def _clean(polyline: NDArray[np.float64]) -> NDArray[np.float64]:
    """Drops repeated points and straight-through vertices."""
    pts = [polyline[0]]
    for p in polyline[1:]:
        if np.hypot(*(p - pts[-1])) > 1e-9:
            pts.append(p)
    out = [pts[0]]
    for k in range(1, len(pts) - 1):
        a, b = pts[k] - out[-1], pts[k + 1] - pts[k]
        cross, dot = a[0] * b[1] - a[1] * b[0], float(a @ b)
        if abs(cross) > 1e-9 * np.hypot(*a) * np.hypot(*b) or dot < 0:
            out.append(pts[k])
    out.append(pts[-1])
    return np.array(out)


def _pieces(
    polyline: NDArray[np.float64],
    speed: float,
    turn_rate: float,
    wiggle: float,
    rng: np.random.Generator,
) -> list[_Piece]:
    pts = _clean(np.asarray(polyline, dtype=np.float64))
    legs = np.diff(pts, axis=0)
    lengths = np.hypot(legs[:, 0], legs[:, 1])
    headings = np.arctan2(legs[:, 1], legs[:, 0])
    turns = [float(wrap_angle(headings[k + 1] - headings[k])) for k in range(len(legs) - 1)]
    # Tangent length cut from each leg at each interior vertex; 0 where the robot turns in place.
    cut = [0.0]
    for k, turn in enumerate(turns):
        if abs(turn) > MAX_ARC_TURN:
            cut.append(0.0)
        else:
            half = math.tan(abs(turn) / 2)
            cut.append(min(CORNER_RADIUS * half, lengths[k] / 2, lengths[k + 1] / 2))
    cut.append(0.0)
    pieces: list[_Piece] = []
    for k in range(len(legs)):
        d = legs[k] / lengths[k]
        length = lengths[k] - cut[k] - cut[k + 1]
        if length > 1e-9:
            pieces.append(
                _Line(
                    pts[k] + cut[k] * d,
                    float(headings[k]),
                    float(length),
                    speed,
                    wiggle * float(rng.uniform(0.5, 1.0)),
                    float(rng.uniform(5.0, 10.0)),
                    float(rng.uniform(0, 2 * np.pi)),
                )
            )
        if k == len(turns):
            break
        turn, tangent = turns[k], cut[k + 1]
        if tangent == 0.0:
            pieces.append(_Turn(pts[k + 1], float(headings[k]), turn, turn_rate))
            continue
        radius = tangent / math.tan(abs(turn) / 2)
        start = pts[k + 1] - tangent * d
        left = np.array([-d[1], d[0]])
        pieces.append(
            _Arc(
                start + math.copysign(radius, turn) * left, radius, float(headings[k]), turn, speed
            )
        )
    return pieces


def follow(
    polyline: NDArray[np.float64],
    *,
    dt: float,
    speed: float,
    turn_rate: float,
    wiggle: float,
    rng: np.random.Generator,
) -> Trajectory:
    """Returns the robot's poses every ``dt`` seconds along a waypoint polyline.

    Args:
        polyline: (K, 2) waypoints.
        dt: Scan period in seconds.
        speed: Driving speed in m/s on legs and corner arcs.
        turn_rate: Rate of turns in place in rad/s.
        wiggle: Largest lateral wiggle on the straight legs, in metres.
        rng: Draws each leg's wiggle (amplitude, wavelength, phase).
    """
    pieces = _pieces(polyline, speed, turn_rate, wiggle, rng)
    starts = np.concatenate([[0.0], np.cumsum([p.duration for p in pieces])])
    times = dt * np.arange(math.floor(starts[-1] / dt + 1e-9) + 1, dtype=np.float64)
    which = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(pieces) - 1)
    poses = np.zeros((len(times), 3))
    for k, piece in enumerate(pieces):
        sel = which == k
        if np.any(sel):
            poses[sel] = piece.poses(np.minimum(times[sel] - starts[k], piece.duration))
    poses[:, 2] = wrap_angle(poses[:, 2])
    return Trajectory(times=times, poses=poses)


def repeat_route(route: NDArray[np.float64], closed: bool, laps: float) -> NDArray[np.float64]:
    """Returns the waypoints of ``laps`` times round a loop, or passes back and forth.

    A fractional lap ends part way along the route, cut by path length.
    """
    route = np.asarray(route, dtype=np.float64)
    rounds = max(1, math.ceil(laps - 1e-9))
    parts = [route]
    for k in range(1, rounds):
        part = route if closed or k % 2 == 0 else route[::-1]
        parts.append(part[1:])
    pts = np.concatenate(parts)
    seg = np.hypot(*np.diff(pts, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    target = laps * float(np.sum(np.hypot(*np.diff(route, axis=0).T)))
    if target >= cum[-1] - 1e-9:
        return pts
    k = int(np.searchsorted(cum, target, side="right"))
    f = (target - cum[k - 1]) / seg[k - 1]
    return np.vstack([pts[:k], pts[k - 1] + f * (pts[k] - pts[k - 1])])
