"""Place recognition: heading invariance, revisits found without any pose, the yaw guess."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.matching.correlative import LoopMatcher, SearchWindow
from vgm_studio.matching.descriptor import DescriptorConfig, PlaceIndex, describe
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.submap import Submap
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.loop_search import trail


@pytest.fixture(scope="module")
def loop_world(tmp_path_factory):
    """The corridor loop driven twice round, with its keyframes and where lap 2 starts."""
    path = simulate(SimConfig(preset="loop", seed=1, laps=2.0), tmp_path_factory.mktemp("sim"))
    log = open_log(path)
    ref = log.reference_poses()
    keyframes = select_keyframes(ref, 1.0, 30.0)
    lap2 = len(log) // 2
    return log, ref, keyframes, lap2


def rotate(points, angle):
    return se2.transform_points(np.array([0.0, 0.0, angle]), points)


def test_ring_key_is_heading_invariant_and_the_shift_gives_the_yaw(loop_world):
    log, *_ = loop_world
    pts = log.scans[120].points()
    index = PlaceIndex()
    index.add(7, pts)
    step = 2 * np.pi / DescriptorConfig().sectors
    for angle in (np.radians(30.0), np.radians(-33.0), np.radians(100.0)):
        turned = rotate(pts, angle)
        np.testing.assert_allclose(describe(turned).ring_key, describe(pts).ring_key, atol=0.02)
        (match,) = index.query(turned, k=1)
        assert match.key == 7
        # Points turned by +angle are what a sensor turned by −angle sees.
        assert abs(se2.wrap_angle(match.yaw + angle)) <= step
        assert match.distance < 0.2
    # A whole number of sectors is an exact shift.
    (match,) = index.query(rotate(pts, 10 * step), k=1)
    assert match.distance == pytest.approx(0.0, abs=1e-9)


def test_lap_two_finds_lap_one_without_any_pose(loop_world):
    # The index never sees a pose, so however far the estimate has drifted by lap 2, the
    # keyframe of lap 1 at the same place must come back among the best few.
    log, ref, keyframes, lap2 = loop_world
    first = keyframes[keyframes < lap2]
    index = PlaceIndex()
    for k in first:
        index.add(int(k), log.scans[k].points())
    found, total, yaw_errors = 0, 0, []
    for q in keyframes[keyframes >= lap2]:
        near = np.hypot(*(ref[first, :2] - ref[q, :2]).T) < 2.0
        same_way = np.abs(se2.wrap_angle(ref[first, 2] - ref[q, 2])) < np.radians(45)
        truth = set(first[near & same_way].tolist())
        if not truth:
            continue
        total += 1
        matches = index.query(log.scans[q].points(), k=10, max_key=int(first[-1]))
        hit = next((m for m in matches if m.key in truth), None)
        if hit is not None:
            found += 1
            yaw_errors.append(abs(se2.wrap_angle(hit.yaw - se2.between(ref[hit.key], ref[q])[2])))
    assert total >= 50
    assert found / total >= 0.75
    # The yaw guess is good to a couple of sectors, well inside a matcher's angular window.
    assert np.degrees(np.median(yaw_errors)) < 6.0


def test_a_place_match_seeds_the_loop_matcher(loop_world):
    # Place recognition then correlative matching, from no pose at all: the guess is only the
    # yaw the descriptor gives, at the keyframe's origin; the submap is the keyframe's
    # neighbours placed by the (locally good) estimate, here the truth.
    log, ref, keyframes, lap2 = loop_world
    first = keyframes[keyframes < lap2]
    index = PlaceIndex()
    for k in first:
        index.add(int(k), log.scans[k].points())
    matcher, window = LoopMatcher(), SearchWindow(3.0, np.radians(30))
    errors = []
    for q in keyframes[keyframes >= lap2][::2]:
        best = index.query(log.scans[q].points(), k=1, max_key=int(first[-1]))[0]
        truth = se2.between(ref[best.key], ref[q])
        if np.hypot(truth[0], truth[1]) > 2.0:
            continue  # a wrong place: the validators' and the consistency check's business
        around = list(range(best.key - 20, best.key + 21, 5))
        sub = Submap.from_scans(
            [log.scans[i] for i in around], se2.between(ref[best.key], ref[around])
        )
        got = matcher.match(sub, log.scans[best.key], log.scans[q], [0, 0, best.yaw], window)
        errors.append(se2.pose_error(truth, got.estimate))
    err = np.array(errors)
    assert len(err) >= 6
    assert np.degrees(err[:, 1].max()) < 1.0
    # Along a featureless corridor only the far end walls fix the position, and a few beams on
    # them can lose to the sampling pattern of the walls: most, not all, are placed.
    assert np.mean(err[:, 0] < 0.05) >= 2 / 3


def test_query_keeps_to_max_key_and_k():
    rng = np.random.default_rng(0)
    index = PlaceIndex()
    assert index.query(rng.uniform(-5, 5, size=(100, 2))) == []
    scans = [rng.uniform(-8, 8, size=(150, 2)) for _ in range(12)]
    for key, pts in enumerate(scans):
        index.add(key * 10, pts)
    index.add(999, rng.uniform(-1, 1, size=(5, 2)))  # too few points: not indexed
    assert len(index) == 12
    got = index.query(scans[9], k=4)
    assert got[0].key == 90 and len(got) == 4
    assert all(a.distance <= b.distance for a, b in itertools.pairwise(got))
    limited = index.query(scans[9], k=4, max_key=40)
    assert len(limited) == 4 and all(m.key <= 40 for m in limited)


def test_a_trail_tells_apart_places_whose_single_scans_look_alike(loop_world):
    # One scan of a corridor looks like many others; the scans of the last metres of the path
    # (placed by the poses, here the truth) add the turns and doors that led there. Lap 2's
    # keyframes, described by their scan alone and by their 10 m trail, against lap 1's.
    log, ref, keyframes, lap2 = loop_world
    scans = [log.scans[k] for k in keyframes]
    poses = ref[keyframes]
    first = int(np.searchsorted(keyframes, lap2))
    one = trail(first + 5, scans, poses, 0.0)
    np.testing.assert_array_equal(one, scans[first + 5].points())
    # The scan before, placed in this keyframe's frame, is part of the trail.
    before = se2.transform_points(
        se2.between(poses[first + 5], poses[first + 4]), scans[first + 4].points()
    )
    longer = trail(first + 5, scans, poses, 10.0)
    assert len(longer) > len(one) + len(before) - 1
    np.testing.assert_allclose(longer[len(one) : len(one) + len(before)], before)
    found = {}
    for metres in (0.0, 10.0):
        index = PlaceIndex()
        for k in range(first):
            index.add(k, trail(k, scans, poses, metres))
        hits = total = 0
        for q in range(first, len(scans)):
            near = np.hypot(*(poses[:first, :2] - poses[q, :2]).T) < 2.0
            same_way = np.abs(se2.wrap_angle(poses[:first, 2] - poses[q, 2])) < np.radians(45)
            truth = set(np.flatnonzero(near & same_way).tolist())
            if not truth:
                continue
            total += 1
            (best,) = index.query(trail(q, scans, poses, metres), k=1, max_key=first - 1)
            hits += best.key in truth and best.distance <= FrontEndConfig().place_max_distance
        found[metres] = hits / total
    assert total >= 50
    assert found[10.0] >= 1.3 * found[0.0], found
