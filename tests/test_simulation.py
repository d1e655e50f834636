"""The corridor simulator: geometry, ray casting, trajectories and the logs it writes."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets.carmen import read_carmen
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.errors import InputError
from vgm_studio.simulation import SimConfig, build_world, plan, preset_names, simulate
from vgm_studio.simulation.raycast import beam_angles, cast
from vgm_studio.simulation.simulate import MISS_MARGIN, scan_ranges
from vgm_studio.simulation.world import (
    corridor_rects,
    door_recesses,
    segment_distances,
    union_walls,
)

# A short drive round the demo loop keeps each log well under a second.
SMALL = SimConfig(preset="demo", seed=7, num_beams=181, laps=0.35, scan_spacing=0.2)


def wall_length(walls: np.ndarray) -> float:
    return float(np.sum(np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])))


@pytest.fixture(scope="module")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ScanLog]:
    path = simulate(SMALL, tmp_path_factory.mktemp("small"))
    return path, read_carmen(path)


# --- geometry ------------------------------------------------------------------------------


def test_union_of_a_cross_has_the_cross_outline() -> None:
    walls = union_walls([(-3.0, -1.0, 3.0, 1.0), (-1.0, -3.0, 1.0, 3.0)])
    # Twelve sides of 2 m each: three per arm.
    assert len(walls) == 12
    assert wall_length(walls) == pytest.approx(24.0)


def test_corridor_ring_has_inner_and_outer_walls() -> None:
    square = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0), (0.0, 0.0)]
    walls = union_walls(corridor_rects(square, 2.0))
    # Outer square 12 m a side, inner 8 m: no slivers at the corners.
    assert len(walls) == 8
    assert wall_length(walls) == pytest.approx(4 * 12.0 + 4 * 8.0)


def test_a_door_recess_notches_the_wall() -> None:
    a, b = (0.0, 0.0), (10.0, 0.0)
    plain = union_walls(corridor_rects([a, b], 2.0))
    doors = door_recesses(a, b, 2.0, pitch=100.0, margin=4.0, depth=0.25, sides=(1,))
    assert len(doors) == 1
    notched = union_walls(corridor_rects([a, b], 2.0) + doors)
    assert wall_length(notched) == pytest.approx(wall_length(plain) + 2 * 0.25)
    assert len(notched) == len(plain) + 4  # the wall is split and the recess has three sides


# --- ray casting ---------------------------------------------------------------------------

CORRIDOR = np.array(
    [
        [-50.0, -1.0, 50.0, -1.0],
        [-50.0, 1.0, 50.0, 1.0],
        [-50.0, -1.0, -50.0, 1.0],
        [50.0, -1.0, 50.0, 1.0],
    ]
)


def test_beams_across_a_corridor_hit_the_side_walls() -> None:
    ranges = cast((0.0, 0.0), [math.pi / 2, -math.pi / 2], CORRIDOR, 30.0)
    np.testing.assert_allclose(ranges, [1.0, 1.0], atol=1e-12)


def test_beams_along_a_long_corridor_return_max_range() -> None:
    assert cast((0.0, 0.0, 1.0), [0.0, math.pi], CORRIDOR, 30.0).tolist() == [30.0, 30.0]
    # With a longer range the end walls come into view.
    np.testing.assert_allclose(cast((0.0, 0.0), [0.0, math.pi], CORRIDOR, 60.0), [50.0, 50.0])


def test_oblique_beams_hit_at_d_over_cos() -> None:
    d = 2.0
    wall = np.array([[d, -10.0, d, 10.0]])
    angles = np.linspace(-1.0, 1.0, 41)
    np.testing.assert_allclose(cast((0.0, 0.0), angles, wall, 30.0), d / np.cos(angles), rtol=1e-12)
    # From a shifted origin the geometry shifts with it.
    np.testing.assert_allclose(
        cast((0.5, 3.0), angles, wall, 30.0), (d - 0.5) / np.cos(angles), rtol=1e-12
    )


def test_people_are_circles_in_front_of_the_walls() -> None:
    centres, radii = np.array([[5.0, 0.0]]), np.array([0.25])
    wall = np.array([[10.0, -5.0, 10.0, 5.0]])
    ranges = cast((0.0, 0.0), [0.0, 0.3], wall, 30.0, centres, radii)
    assert ranges[0] == pytest.approx(4.75)
    assert ranges[1] == pytest.approx(10.0 / math.cos(0.3))  # misses the person
    # A person standing on the sensor does not blind it.
    assert cast((5.0, 0.0), [0.0], wall, 30.0, centres, radii)[0] == pytest.approx(5.0)


def test_beam_angles_span_the_field_of_view() -> None:
    assert beam_angles(361, 180.0) == pytest.approx((-math.pi / 2, math.pi / 360))
    assert beam_angles(271, 270.0) == pytest.approx((-3 * math.pi / 4, math.pi / 180))
    # A full circle has no duplicate beam at +180°.
    assert beam_angles(720, 360.0) == pytest.approx((-math.pi, 2 * math.pi / 720))


def test_ray_casting_is_fast() -> None:
    rng = np.random.default_rng(1)
    walls = rng.uniform(-15.0, 15.0, size=(300, 4))
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    best = math.inf
    for _ in range(20):
        start = time.perf_counter()
        cast((0.0, 0.0), angles, walls, 30.0)
        best = min(best, time.perf_counter() - start)
    assert best < 0.005


# --- presets and trajectories --------------------------------------------------------------


def test_unknown_preset_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="unknown preset 'nope'") as info:
        build_world("nope")
    assert "office" in str(info.value) and "demo" in str(info.value)
    with pytest.raises(InputError, match="unknown preset"):
        simulate(SimConfig(preset="nope"), tmp_path)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "bad",
    [
        {"num_beams": 1},
        {"fov_deg": 0.0},
        {"fov_deg": 400.0},
        {"max_range": -1.0},
        {"scan_spacing": 0.0},
        {"people": -2},
        {"laps": 0.0},
        {"range_noise": -0.1},
    ],
)
def test_bad_config_values_are_input_errors(bad: dict[str, float]) -> None:
    with pytest.raises(InputError):
        SimConfig(**bad)  # type: ignore[arg-type]


@pytest.mark.parametrize("name", preset_names())
def test_route_keeps_clear_of_walls(name: str) -> None:
    p = plan(SimConfig(preset=name, people=4))
    clearance = segment_distances(p.truth.poses[:, :2], p.world.walls)
    assert clearance.min() > 0.5
    # People walk on their own lane: they never reach the robot.
    for k in range(0, len(p.truth), 5):
        centres, radii = p.world.people_at(float(p.truth.times[k]))
        gaps = np.hypot(*(centres - p.truth.poses[k, :2]).T) - radii
        assert gaps.min() > 0.15


@pytest.mark.parametrize("name", ["loop", "repetitive", "office", "demo"])
def test_loops_revisit_places(name: str) -> None:
    truth = plan(SimConfig(preset=name)).truth
    xy, t = truth.poses[:, :2], truth.times
    close = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) < 1.0
    apart = np.abs(t[:, None] - t[None, :]) > 20.0
    assert np.any(close & apart)


def test_corridor_is_one_long_straight_run() -> None:
    p = plan(SimConfig(preset="corridor"))
    assert p.truth.travelled() > 50.0
    assert np.ptp(p.truth.poses[:, 1]) < 0.5
    assert np.max(np.abs(p.truth.poses[:, 2])) < 0.3


def test_heading_follows_the_path() -> None:
    poses = plan(SimConfig(preset="l-junction")).truth.poses
    step = np.diff(poses[:, :2], axis=0)
    moving = np.hypot(*step.T) > 1e-6
    direction = np.arctan2(step[moving, 1], step[moving, 0])
    mid_heading = poses[:-1][moving, 2] + se2.wrap_angle(np.diff(poses[:, 2]))[moving] / 2
    assert np.max(np.abs(se2.wrap_angle(direction - mid_heading))) < 0.05
    # It turns left by 90° at the junction.
    assert poses[0, 2] == pytest.approx(0.0, abs=0.1)
    assert poses[-1, 2] == pytest.approx(math.pi / 2, abs=0.1)


def test_dead_ends_are_turned_in_place_with_scans() -> None:
    poses = plan(SimConfig(preset="t-junction")).truth.poses
    still = np.hypot(*np.diff(poses[:, :2], axis=0).T) < 1e-9
    turning = np.abs(se2.wrap_angle(np.diff(poses[:, 2]))) > 1e-3
    assert np.count_nonzero(still & turning) >= 10


# --- logs ----------------------------------------------------------------------------------


def test_log_reads_back_with_true_reference_poses(small_log: tuple[Path, ScanLog]) -> None:
    path, log = small_log
    p = plan(SMALL)
    assert path.name == "demo-seed7.log"
    assert len(log) == len(p.truth) > 20
    # About one scan per scan_spacing metres driven.
    assert len(log) == pytest.approx(p.truth.travelled() / SMALL.scan_spacing, rel=0.05)
    assert log.pose_source == "odometry" and log.reference_origin == "TRUEPOS"
    assert log.message_counts["ODOM"] == log.message_counts["TRUEPOS"] == len(log)
    np.testing.assert_allclose(np.diff(log.timestamps), SMALL.scan_period, atol=2e-6)
    ref = log.reference_poses()
    assert ref is not None
    np.testing.assert_allclose(ref[:, :2], p.truth.poses[:, :2], atol=1e-5)
    assert np.max(np.abs(se2.wrap_angle(ref[:, 2] - p.truth.poses[:, 2]))) < 1e-5


def test_odometry_is_noisy_but_plausible(small_log: tuple[Path, ScanLog]) -> None:
    _, log = small_log
    ref, odom = log.reference_poses(), log.odometry_poses()
    assert ref is not None and odom is not None
    err = np.hypot(*(odom[:, :2] - ref[:, :2]).T)
    assert err[0] < 1e-5
    assert err.max() > 1e-3
    assert err.max() < 0.1 * log.travelled_distance() + 0.2
    # Consecutive odometry steps stay close to the true steps.
    step_err = se2.between(ref[:-1], ref[1:]) - se2.between(odom[:-1], odom[1:])
    assert np.max(np.abs(step_err[:, :2])) < 0.05


def test_points_lie_on_the_walls(small_log: tuple[Path, ScanLog]) -> None:
    _, log = small_log
    walls = plan(SMALL).world.walls
    bound = 5 * SMALL.range_noise + 0.005  # plus rounding of ranges and angles in the log
    total = 0
    for scan in log.scans:
        assert scan.reference is not None
        points = se2.transform_points(scan.reference, scan.points())
        assert len(points) > 0.9 * scan.num_beams  # the demo loop is small: almost all hit
        assert segment_distances(points, walls).max() < bound
        total += len(points)
    assert total > 1000


def test_header_names_generator_and_every_config_value(small_log: tuple[Path, ScanLog]) -> None:
    path, _ = small_log
    header = [line for line in path.read_text().splitlines() if line.startswith("#")]
    text = "\n".join(header)
    assert "vgm-studio" in text and "simulate" in text
    for field in dataclasses.fields(SimConfig):
        assert f"{field.name} = {getattr(SMALL, field.name)!r}" in text
    assert path.read_text().startswith("#")


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path: Path) -> None:
    a = simulate(SMALL, tmp_path / "a").read_bytes()
    b = simulate(SMALL, tmp_path / "b").read_bytes()
    c = simulate(dataclasses.replace(SMALL, seed=8), tmp_path / "c").read_bytes()
    assert a == b
    assert a != c


def test_full_circle_scans(tmp_path: Path) -> None:
    config = dataclasses.replace(SMALL, num_beams=720, fov_deg=360.0, laps=0.1)
    log = read_carmen(simulate(config, tmp_path))
    scan = log.scans[0]
    assert scan.num_beams == 720
    assert scan.angle_min == pytest.approx(-math.pi, abs=1e-6)
    assert scan.angle_increment == pytest.approx(2 * math.pi / 720, abs=1e-6)
    assert scan.angles()[-1] + scan.angle_increment == pytest.approx(math.pi, abs=1e-3)
    # Walls all round: points behind the robot too.
    pts = scan.points()
    assert np.count_nonzero(pts[:, 0] < -0.5) > 100
    assert np.count_nonzero(pts[:, 0] > 0.5) > 100


def test_270_degree_field_of_view(tmp_path: Path) -> None:
    config = dataclasses.replace(SMALL, num_beams=541, fov_deg=270.0, laps=0.1)
    scan = read_carmen(simulate(config, tmp_path)).scans[0]
    assert scan.num_beams == 541
    assert scan.angle_min == pytest.approx(-3 * math.pi / 4, abs=1e-6)
    assert scan.fov == pytest.approx(3 * math.pi / 2, abs=1e-3)


def test_max_range_marks_misses(tmp_path: Path) -> None:
    config = dataclasses.replace(SMALL, max_range=4.0, laps=0.2)
    log = read_carmen(simulate(config, tmp_path))
    ranges = np.concatenate([s.ranges for s in log.scans])
    misses = ranges >= 4.0
    assert np.any(misses) and np.any(~misses)
    np.testing.assert_allclose(ranges[misses], 4.0 + MISS_MARGIN, atol=1e-6)
    assert all(s.max_range == 4.0 for s in log.scans)
    assert all(np.hypot(*s.points().T).max() < 4.0 for s in log.scans)


@pytest.mark.parametrize("sigma", [0.0, 0.05])
def test_range_noise_has_the_configured_sigma(tmp_path: Path, sigma: float) -> None:
    config = dataclasses.replace(SMALL, range_noise=sigma, laps=0.15)
    log = read_carmen(simulate(config, tmp_path))
    p = plan(config)
    residuals = []
    for k, scan in enumerate(log.scans):
        exact = scan_ranges(p, k, np.zeros(config.num_beams))
        hit = (exact < config.max_range) & (scan.ranges < config.max_range)
        residuals.append(scan.ranges[hit] - exact[hit])
    r = np.concatenate(residuals)
    assert len(r) > 2000
    if sigma == 0.0:
        assert np.abs(r).max() < 1e-3  # only the log's millimetre rounding
    else:
        assert np.std(r) == pytest.approx(sigma, rel=0.1)
        assert abs(np.mean(r)) < 0.1 * sigma


def test_people_occlude_walls_and_move(tmp_path: Path) -> None:
    base = dataclasses.replace(SMALL, laps=0.3)
    crowd = dataclasses.replace(base, people=3)
    empty = read_carmen(simulate(base, tmp_path / "empty"))
    busy = read_carmen(simulate(crowd, tmp_path / "busy"))
    a = np.stack([s.ranges for s in empty.scans])
    b = np.stack([s.ranges for s in busy.scans])
    changed = a != b
    assert np.count_nonzero(np.any(changed, axis=1)) >= 3  # seen in several scans
    # People only ever block the view: same noise, shorter ranges.
    assert np.all(b[changed] < a[changed])
    world, times = plan(crowd).world, plan(crowd).truth.times
    before, _ = world.people_at(float(times[0]))
    after, _ = world.people_at(float(times[1]))
    assert len(before) == 3
    assert np.all(np.hypot(*(after - before).T) > 0.01)
    # Other presets carry walkways for people too.
    for name in preset_names():
        assert len(plan(SimConfig(preset=name, people=2)).world.people) == 2


def test_bundled_demo_log_is_remade_by_its_command(tmp_path: Path) -> None:
    """The shipped demo log is exactly what README's command makes (same seed, same bytes)."""
    bundled = Path(__file__).resolve().parents[1] / "datasets" / "demo-seed0.log"
    made = simulate(SimConfig(preset="demo", seed=0), tmp_path)
    assert made.name == bundled.name
    if made.read_bytes() != bundled.read_bytes():
        pairs = zip(made.read_text().splitlines(), bundled.read_text().splitlines(), strict=False)
        first = next(i for i, (a, b) in enumerate(pairs, 1) if a != b)
        pytest.fail(f"{bundled.name} differs from a fresh simulation at line {first}")
