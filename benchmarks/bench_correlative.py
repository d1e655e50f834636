"""The loop matcher and place recognition: speed, convergence from metres off, recall@k.

1. Speed: ms per loop query over a 6 m × 6 m × ±30° window at 5 cm on one core (target ≤ 20),
   and branch and bound against brute force over the same discretisation, in the same run.
   Times are CPU time of this process (``time.process_time``), as the machine is shared.
2. Convergence: loop pairs (≥ 50 scans apart, ≤ 3 m) guessed 0.5 m/5°, 1 m/10° and 2 m/25° off
   the reference, LoopMatcher (window 3 m/30°, submap of the target keyframe ± 2 keyframes)
   against the pairwise ScanMatcher; converged = within 0.1 m and 2° of the reference.
3. Place recognition: recall@k of the Scan Context index. Every keyframe (1 m / 30°) queries the
   keyframes at least 20 m of travel before it; a revisit is a query with one of those within
   2 m and 45°, and it is found when one such keyframe is among the k best. Each keyframe is
   described by its scan alone, then by its 10 m trail (``slam.loop_search.trail``, placed by
   the reference poses): the SLAM front end proposes the best of both.

Run: python benchmarks/bench_correlative.py [--quick]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import datasets_dir, machine, pin_to_cores, table

OFFSETS = ((0.5, 5.0), (1.0, 10.0), (2.0, 25.0))
GAP_METRES = 20.0
SPAN = 2  # keyframes each side of the loop target in its submap
RECALL_K = (1, 5, 10)
# Each keyframe described by its scan alone, and by its trail: the SLAM front end uses both.
TRAILS = (0.0, 10.0)
CORRECTED = ("intel/intel.gfs.log", *(f"radish-corrected/{n}-corrected.log" for n in (
    "fhw", "csail", "freiburg-101", "orebro", "infinite-corridor")))  # fmt: skip


def _keyframes(ref):
    from vgm_studio.matching.keyframes import select_keyframes

    return select_keyframes(ref, 1.0, 30.0)


def _submap(log, ref, keyframes, j):
    """The target keyframe j's submap: keyframes j−2..j+2 placed by the reference."""
    from vgm_studio.core import se2
    from vgm_studio.matching.submap import Submap

    near = keyframes[max(0, j - SPAN) : j + SPAN + 1]
    a = keyframes[j]
    return Submap.from_scans([log.scans[i] for i in near], se2.between(ref[a], ref[near]))


def _loop_cases(log, count, seed):
    """(submap, a, b, truth) for loop pairs among keyframes, sampled with ``seed``."""
    from vgm_studio.core import se2
    from vgm_studio.matching.candidates import CandidateConfig, loop_pairs

    ref = log.reference_poses()
    kf = _keyframes(ref)
    pairs = loop_pairs(ref[kf], CandidateConfig(max_loops=count, seed=seed, min_gap=10))
    return [
        (_submap(log, ref, kf, int(i)), int(kf[i]), int(kf[j]), se2.between(ref[kf[i]], ref[kf[j]]))
        for i, j in pairs
    ]


def _offset(rng, metres, degrees):
    phi = rng.uniform(0, 2 * np.pi)
    return np.array(
        [metres * np.cos(phi), metres * np.sin(phi), rng.choice([-1, 1]) * np.radians(degrees)]
    )


def speed_rows(name, log, cases, brute):
    """Median and p90 ms per query, search alone and whole match, and the brute-force ratio."""
    from vgm_studio.matching.correlative import LoopMatcher, SearchWindow, brute_force

    matcher, window = LoopMatcher(), SearchWindow(3.0, np.radians(30))
    rng = np.random.default_rng(1)
    search, whole, evals, bnb_of, same = [], [], [], {}, 0
    for k, (sub, a, b, truth) in enumerate(cases):
        guess = truth + _offset(rng, 2.0, 25.0)
        matcher.match(sub, log.scans[a], log.scans[b], guess, window)  # padding cached per submap
        t = time.process_time()
        hit = matcher.search(sub, log.scans[b], guess, window)
        search.append(time.process_time() - t)
        t = time.process_time()
        matcher.match(sub, log.scans[a], log.scans[b], guess, window)
        whole.append(time.process_time() - t)
        evals.append(hit.evaluated if hit else 0)
        if k < brute and hit is not None:
            t = time.process_time()
            slow = brute_force(sub, matcher.points(log.scans[b]), guess, window)
            bnb_of[k] = (time.process_time() - t) / search[-1]
            same += int(slow is not None and slow.index == hit.index)
    ms = np.array(search) * 1e3
    ratio = f"{np.median(list(bnb_of.values())):.0f}× ({same}/{len(bnb_of)} same pose)"
    return [
        name,
        str(len(cases)),
        f"{np.median(ms):.1f}",
        f"{np.percentile(ms, 90):.1f}",
        f"{np.median(whole) * 1e3:.1f}",
        f"{np.median(evals):.0f}",
        ratio if bnb_of else "–",
    ]


def convergence_rows(name, log, cases):
    """Share of pairs within 0.1 m / 2° after each matcher, per starting offset."""
    from vgm_studio.core import se2
    from vgm_studio.matching.correlative import LoopMatcher, SearchWindow
    from vgm_studio.matching.matcher import ScanMatcher

    loop, pairwise = LoopMatcher(), ScanMatcher()
    window = SearchWindow(3.0, np.radians(30))
    rows = []
    for metres, degrees in OFFSETS:
        rng = np.random.default_rng(2)
        ok: dict[str, list[bool]] = {"LoopMatcher": [], "ScanMatcher": []}
        for sub, a, b, truth in cases:
            guess = truth + _offset(rng, metres, degrees)
            est = {
                "LoopMatcher": loop.match(sub, log.scans[a], log.scans[b], guess, window).estimate,
                "ScanMatcher": pairwise.match(log.scans[a], log.scans[b], guess).estimate,
            }
            for key, pose in est.items():
                dxy, dth = se2.pose_error(truth, pose)
                ok[key].append(dxy <= 0.1 and np.degrees(dth) <= 2.0)
        rows.append(
            [name, f"{metres} m / {degrees:.0f}°", str(len(cases))]
            + [f"{np.mean(ok[k]):.2f}" for k in ("LoopMatcher", "ScanMatcher")]
        )
    return rows


def recall_row(name, log, trail_metres=0.0):
    """Recall@k of the place index over the log's revisits (see the module docstring), each
    keyframe described by its trail of ``trail_metres`` (0: its scan alone)."""
    from vgm_studio.core import se2
    from vgm_studio.matching.descriptor import PlaceIndex
    from vgm_studio.slam.loop_search import trail

    ref = log.reference_poses()
    kf = _keyframes(ref)
    scans, poses = [log.scans[i] for i in kf], ref[kf]
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ref[:, :2], axis=0).T))])[kf]
    index, found, total, secs = PlaceIndex(), dict.fromkeys(RECALL_K, 0), 0, []
    added = 0
    for q in range(len(kf)):
        while added < len(kf) and travel[added] <= travel[q] - GAP_METRES:
            index.add(added, trail(added, scans, poses, trail_metres))
            added += 1
        near = np.hypot(*(poses[:added, :2] - poses[q, :2]).T) < 2.0
        same_way = np.abs(se2.wrap_angle(poses[:added, 2] - poses[q, 2])) < np.radians(45)
        truth = set(np.flatnonzero(near & same_way).tolist())
        if not truth:
            continue
        total += 1
        t = time.perf_counter()
        got = index.query(trail(q, scans, poses, trail_metres), k=max(RECALL_K))
        secs.append(time.perf_counter() - t)
        for k in RECALL_K:
            found[k] += any(m.key in truth for m in got[:k])
    cells = [f"{found[k] / total:.2f}" if total else "–" for k in RECALL_K]
    described = f"{trail_metres:.0f} m trail" if trail_metres else "scan"
    return [name, described, str(len(kf)), str(total), *cells, f"{np.median(secs) * 1e3:.1f}"]


def main() -> None:
    quick = "--quick" in sys.argv
    pin_to_cores(1)
    from vgm_studio.datasets import open_log
    from vgm_studio.simulation.simulate import SimConfig, simulate

    data = datasets_dir()
    pairs, brute = (8, 1) if quick else (40, 3)
    intel = open_log(data / "intel/intel.gfs.log")
    with tempfile.TemporaryDirectory() as tmp:
        sims = {
            p: open_log(simulate(SimConfig(preset=p, seed=11, laps=2.0), Path(tmp)))
            for p in ("office", "loop", "repetitive")
        }
        logs = {"sim office (361 beams)": sims["office"], "Intel (180 beams)": intel}
        cases = {n: _loop_cases(log, pairs, seed=0) for n, log in logs.items()}
        print(f"# {machine()}, one core\n")
        print("## Speed: one loop query, 6 m × 6 m × ±30° at 5 cm, guess 2 m / 25° off\n")
        header = ["pairs", "queries", "search ms (median)", "p90", "match ms", "candidates"]
        rows = [speed_rows(n, logs[n], cases[n], brute) for n in logs]
        print(table([*header, "brute force / B&B"], rows))
        print("\n## Convergence (within 0.1 m and 2° of the reference)\n")
        rows = [r for n in logs for r in convergence_rows(n, logs[n], cases[n])]
        print(table(["pairs", "guess off by", "pairs", "LoopMatcher", "ScanMatcher"], rows))
        print(f"\n## Place recognition recall@k (queries ≥ {GAP_METRES:.0f} m of travel on)\n")
        rows = [
            recall_row(f"sim {p}, 2 laps", log, metres)
            for p, log in sims.items()
            for metres in TRAILS
        ]
    for rel in CORRECTED[:2] if quick else CORRECTED:
        log = open_log(data / rel)
        rows += [recall_row(Path(rel).name, log, metres) for metres in TRAILS]
    header = ["log", "described by", "keyframes", "revisits"]
    header += [*(f"@{k}" for k in RECALL_K), "query ms"]
    print(table(header, rows))


if __name__ == "__main__":
    main()
