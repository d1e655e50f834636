"""Simulated CARMEN logs: ray-cast scans, true poses and noisy odometry.

Each scan is written as three messages with one timestamp::

    ODOM x y θ tv rv accel          noisy odometry pose (accel 0)
    TRUEPOS x y θ ox oy oθ          true pose, then the odometry pose
    ROBOTLASER1 … laser pose …      the scan; its pose fields carry odometry, as raw logs do

``read_carmen`` takes the reference poses from ``TRUEPOS`` and the odometry from the scans.

Odometry noise is a random walk whose variance grows with the distance driven (and the angle
turned), so it does not depend on the scan spacing. Each step of d metres and Δθ radians adds,
in the robot frame,

* Gaussian x and y errors of σ = ``odom_trans_noise`` · √d (defaults: 2 cm after 1 m,
  20 cm after 100 m),
* a Gaussian heading error of σ² = (``odom_rot_noise_deg`` in rad)² · d
  + ``odom_turn_noise``² · |Δθ| (0.5° after 1 m, 5° after 100 m; 0.02 rad after turning
  1 rad in place),
* a systematic heading drift of ``odom_drift_deg`` per metre (counter-clockwise), as unequal
  wheel radii would give.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio import __version__
from vgm_studio.core import se2
from vgm_studio.datasets.carmen import format_pose_message, format_robotlaser
from vgm_studio.errors import InputError
from vgm_studio.progress import track
from vgm_studio.simulation.presets import build_world
from vgm_studio.simulation.raycast import beam_angles, cast
from vgm_studio.simulation.trajectory import Trajectory, follow, repeat_route
from vgm_studio.simulation.world import World

# Misses are written this far beyond max_range, so that a reader comparing float32 ranges with
# ``r >= max_range`` (or ``r > max_range``) still sees "no return" for any max_range.
MISS_MARGIN = 0.001


@dataclass(frozen=True)
class SimConfig:
    """Everything a simulated log depends on; the same config gives the same bytes.

    Attributes:
        preset: World name; see ``presets.preset_names()``.
        seed: Seeds every random draw (wiggle, odometry noise, range noise, people).
        num_beams: Beams per scan.
        fov_deg: Field of view in degrees, up to 360 (a full circle, no repeated beam).
        range_noise: σ of the Gaussian noise on each return, metres (misses stay exact).
        max_range: Sensor range, metres; beams that hit nothing read as "no return".
        people: People walking back and forth in the corridors.
        scan_spacing: Metres driven between scans; the scan period is ``scan_spacing / speed``.
        speed: Driving speed, m/s.
        turn_rate_deg: Speed of turns in place, °/s.
        wiggle: Largest sideways wander off the corridor centre line, metres.
        laps: Times round a loop, or passes of an open route (back and forth); fractions end
            part way. ``None`` takes the preset's own.
        odom_trans_noise: Odometry x/y error σ after 1 m driven, as a fraction (metres per √m).
        odom_rot_noise_deg: Odometry heading error σ after 1 m driven, degrees (per √m).
        odom_turn_noise: Odometry heading error σ after turning 1 rad, radians (per √rad).
        odom_drift_deg: Systematic odometry heading drift, degrees per metre driven.
    """

    preset: str = "office"
    seed: int = 0
    num_beams: int = 361
    fov_deg: float = 180.0
    range_noise: float = 0.01
    max_range: float = 30.0
    people: int = 0
    scan_spacing: float = 0.1
    speed: float = 1.0
    turn_rate_deg: float = 45.0
    wiggle: float = 0.1
    laps: float | None = None
    odom_trans_noise: float = 0.02
    odom_rot_noise_deg: float = 0.5
    odom_turn_noise: float = 0.02
    odom_drift_deg: float = 0.05

    def __post_init__(self) -> None:
        checks = [
            (self.num_beams >= 2, f"num_beams must be at least 2, got {self.num_beams}"),
            (0.0 < self.fov_deg <= 360.0, f"fov_deg must be in (0, 360], got {self.fov_deg}"),
            (self.max_range > 0.0, f"max_range must be positive, got {self.max_range}"),
            (self.range_noise >= 0.0, f"range_noise must be ≥ 0, got {self.range_noise}"),
            (self.people >= 0, f"people must be ≥ 0, got {self.people}"),
            (self.scan_spacing > 0.0, f"scan_spacing must be positive, got {self.scan_spacing}"),
            (self.speed > 0.0, f"speed must be positive, got {self.speed}"),
            (self.turn_rate_deg > 0.0, f"turn_rate_deg must be positive, got {self.turn_rate_deg}"),
            (self.wiggle >= 0.0, f"wiggle must be ≥ 0, got {self.wiggle}"),
            (self.laps is None or self.laps > 0.0, f"laps must be positive, got {self.laps}"),
        ]
        noise = (
            self.odom_trans_noise,
            self.odom_rot_noise_deg,
            self.odom_turn_noise,
            self.odom_drift_deg,
        )
        checks.append(
            (
                all(math.isfinite(v) for v in noise) and min(noise[:3]) >= 0.0,
                "odometry noise must be finite and ≥ 0",
            )
        )
        for ok, message in checks:
            if not ok:
                raise InputError(None, message)

    @property
    def scan_period(self) -> float:
        """Seconds between scans."""
        return self.scan_spacing / self.speed

    def file_name(self) -> str:
        """The log's file name, ``<preset>-seed<seed>.log``."""
        return f"{self.preset}-seed{self.seed}.log"


@dataclass(frozen=True, eq=False)
class SimPlan:
    """What a config makes before any ray is cast: the world, true poses and odometry."""

    config: SimConfig
    world: World
    truth: Trajectory
    odometry: NDArray[np.float64]

    def beam_angles(self) -> NDArray[np.float64]:
        """(N,) beam angles in the laser frame, radians."""
        angle_min, increment = beam_angles(self.config.num_beams, self.config.fov_deg)
        return angle_min + increment * np.arange(self.config.num_beams, dtype=np.float64)


def _streams(seed: int) -> list[np.random.Generator]:
    # Independent streams, so that adding people or changing the beam count leaves the route
    # and the odometry noise of a seed unchanged.
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)]


def noisy_odometry(
    truth: NDArray[np.float64], config: SimConfig, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Returns odometry poses that start at the true start and drift (see the module doc)."""
    steps = se2.between(truth[:-1], truth[1:])
    dist = np.hypot(steps[:, 0], steps[:, 1])
    sigma_xy = config.odom_trans_noise * np.sqrt(dist)
    sigma_theta = np.sqrt(
        math.radians(config.odom_rot_noise_deg) ** 2 * dist
        + config.odom_turn_noise**2 * np.abs(steps[:, 2])
    )
    draws = rng.standard_normal((len(steps), 3))
    noisy = steps + np.stack(
        [
            sigma_xy * draws[:, 0],
            sigma_xy * draws[:, 1],
            sigma_theta * draws[:, 2] + math.radians(config.odom_drift_deg) * dist,
        ],
        axis=1,
    )
    heading = truth[0, 2] + np.concatenate([[0.0], np.cumsum(noisy[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    x = truth[0, 0] + np.concatenate([[0.0], np.cumsum(c * noisy[:, 0] - s * noisy[:, 1])])
    y = truth[0, 1] + np.concatenate([[0.0], np.cumsum(s * noisy[:, 0] + c * noisy[:, 1])])
    return np.stack([x, y, se2.wrap_angle(heading)], axis=1)


def plan(config: SimConfig) -> SimPlan:
    """Builds the world and the robot's true and odometry poses of a config (no ray casting).

    Raises:
        InputError: Unknown preset.
    """
    route_rng, odom_rng, _, people_rng = _streams(config.seed)
    world = build_world(config.preset).with_people(config.people, people_rng)
    laps = world.default_laps if config.laps is None else config.laps
    truth = follow(
        repeat_route(world.route, world.closed, laps),
        dt=config.scan_period,
        speed=config.speed,
        turn_rate=math.radians(config.turn_rate_deg),
        wiggle=config.wiggle,
        rng=route_rng,
    )
    return SimPlan(config, world, truth, noisy_odometry(truth.poses, config, odom_rng))


# The first line of every simulated log says so: training tells our worlds from real logs by it.
SIMULATED_MARK = "simulate: synthetic CARMEN log"


def is_simulated(log: str | Path) -> bool:
    """Whether ``log`` was written by ``simulate`` (a log that cannot be read is not)."""
    try:
        with open(log, encoding="utf-8", errors="replace") as f:
            return SIMULATED_MARK in f.readline()
    except OSError:
        return False


def _header(p: SimPlan) -> list[str]:
    c = p.config
    lines = [
        f"# vgm-studio {__version__} {SIMULATED_MARK} (vgm_studio.simulation)",
        f"# world: {p.world.description}",
        f"# scans: {len(p.truth)}, travelled: {p.truth.travelled():.2f} m, "
        f"scan period: {c.scan_period:.6g} s",
        "# per scan: ODOM (noisy odometry), TRUEPOS (true pose, odometry pose), ROBOTLASER1",
        "#   (laser pose = odometry pose); misses read max_range + 0.001",
        "# config:",
    ]
    lines += [f"#   {f.name} = {getattr(c, f.name)!r}" for f in fields(c)]
    return lines


def scan_ranges(p: SimPlan, k: int, noise: NDArray[np.float64]) -> NDArray[np.float64]:
    """Returns scan ``k``'s ranges: true ranges plus ``noise`` on hits, misses past max_range."""
    c = p.config
    pose = p.truth.poses[k]
    centres, radii = p.world.people_at(float(p.truth.times[k]))
    ranges = cast(pose, pose[2] + p.beam_angles(), p.world.walls, c.max_range, centres, radii)
    noisy = ranges + noise
    # Noise may carry a far return past the range; the sensor would report nothing then.
    return np.where(
        (ranges < c.max_range) & (noisy < c.max_range), noisy, c.max_range + MISS_MARGIN
    )


def simulate(config: SimConfig, out_dir: Path) -> Path:
    """Writes ``out_dir/<preset>-seed<seed>.log`` and returns its path.

    Raises:
        InputError: Unknown preset.
    """
    p = plan(config)
    range_rng = _streams(config.seed)[2]
    angle_min, increment = beam_angles(config.num_beams, config.fov_deg)
    lines = _header(p)
    odom = p.odometry
    steps = se2.between(odom[np.maximum(np.arange(len(odom)) - 1, 0)], odom)
    for k in track(range(len(p.truth)), f"simulate {config.preset}", "scan"):
        t = float(p.truth.times[k])
        noise = config.range_noise * range_rng.standard_normal(config.num_beams)
        ranges = scan_ranges(p, k, noise)
        velocity = (steps[k, 0] / config.scan_period, steps[k, 2] / config.scan_period, 0.0)
        lines.append(format_pose_message("ODOM", odom[k], velocity, t))
        lines.append(format_pose_message("TRUEPOS", p.truth.poses[k], odom[k], t))
        lines.append(
            format_robotlaser(
                ranges,
                angle_min=angle_min,
                angle_increment=increment,
                max_range=config.max_range,
                laser_pose=odom[k],
                timestamp=t,
            )
        )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / config.file_name()
    with path.open("w", encoding="utf-8", newline="\n") as f:
        f.write("\n".join(lines) + "\n")
    return path
