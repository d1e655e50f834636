"""The anchors between keyframes refined in a spawned process while the odometry is made.

The odometry is one thread of kiss-icp, so the second core is idle while it runs, and an
anchor's refinement needs only the odometry up to the next keyframe. The worker is told each
scan's pose as it is made, picks the keyframes and anchors as the run will (``KeyframePicker``,
as ``select_keyframes`` does), and refines each anchor as soon as both of its
keyframes are known. At the end the run hands it its keyframes: where they differ from the
worker's, or the worker failed, the placements are made afterwards (``place_between``), so
the result is ``place_between``'s either way.
"""

from __future__ import annotations

import contextlib
import queue
import weakref
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.keyframes import KeyframePicker
from vgm_studio.processes import exit_with_parent, keep_for_good, start_worker
from vgm_studio.slam.between import (
    ANCHOR_ANGLE_DEG,
    ANCHOR_DISTANCE,
    BetweenPlacements,
    Refiner,
    place_between,
)

# Poses sent to the worker at a time.
_CHUNK = 256

# Scans a log has at least for its anchors to be refined by the worker: its start (2–3 s of
# imports on a core the front end then shares) costs a short log more than the refinements
# (the 378-scan demo: 5 s in all inline, 11 s with the worker).
STREAM_FROM = 2000


class BetweenStream:
    """Feeds the odometry to a worker that refines the anchors meanwhile.

    Args:
        scans: Every scan of the log.
        usable: Which scans may be keyframes.
        keyframe_step: The run's keyframe distance (metres) and angle (degrees).

    Raises:
        OSError, RuntimeError: No process can start here.
    """

    def __init__(
        self, scans: Sequence[Scan], usable: NDArray[np.bool_], keyframe_step: tuple[float, float]
    ) -> None:
        self._scans = scans
        first = ("scans", list(scans), usable, keyframe_step)
        self._proc, self._to, self._back = start_worker(_work, first)
        # Stopped however the run ends (an error before ``result``, say).
        self._stop = weakref.finalize(self, _stop, self._proc, self._to)
        self._start = 0
        self._buffer: list[NDArray[np.float64]] = []

    def pose(self, i: int, pose: NDArray[np.float64]) -> None:
        """Scan ``i``'s final odometry pose (in scan order)."""
        self._buffer.append(np.array(pose, dtype=np.float64))
        if len(self._buffer) >= _CHUNK:
            self._flush()

    def result(
        self, odometry: NDArray[np.float64], keyframes: NDArray[np.int64], progress: bool = True
    ) -> BetweenPlacements:
        """The worker's placements where it picked ``keyframes`` too, else made here."""
        found = None
        try:
            self._flush()
            self._to.put(("done", np.asarray(keyframes)))
            # Waits while the worker lives: one that died sends nothing.
            while self._proc.is_alive():
                with contextlib.suppress(queue.Empty):
                    found = self._back.get(timeout=1.0)
                    break
        except (OSError, ValueError):
            found = None
        finally:
            self._stop()
        if isinstance(found, BetweenPlacements):
            return found
        return place_between(self._scans, odometry, keyframes, progress)

    def _flush(self) -> None:
        if self._buffer:
            self._to.put(("poses", self._start, np.stack(self._buffer)))
            self._start += len(self._buffer)
            self._buffer = []


def _stop(proc: Any, to: Any) -> None:
    with contextlib.suppress(OSError, ValueError):
        to.put(("stop",))
    proc.join(timeout=5.0)
    if proc.is_alive():
        proc.terminate()


def _work(to: Any, back: Any) -> None:
    exit_with_parent()
    # The queue's first message, always: ``BetweenStream`` puts it before any other.
    given: tuple[str, list[Scan], NDArray[np.bool_], tuple[float, float]] = to.get()
    _, scans, usable, keyframe_step = given
    keep_for_good()  # the scans live as long as this worker
    odometry = np.full((len(scans), 3), np.nan)
    refine = Refiner(scans, odometry)
    # The run picks keyframes among the usable scans and anchors among all (``place_between``).
    pick_key = KeyframePicker(*keyframe_step)
    pick_anchor = KeyframePicker(ANCHOR_DISTANCE, ANCHOR_ANGLE_DEG)
    keyframes: list[int] = []
    index: list[int] = []
    before: list[int] = []
    pose_before: list[NDArray[np.float64]] = []
    pose_after: dict[int, NDArray[np.float64]] = {}
    share: dict[int, float] = {}
    waiting: list[int] = []  # rows whose keyframe after is not known yet
    while True:
        message = to.get()
        if message[0] == "stop":
            return
        if message[0] == "done":
            break
        _, start, poses = message
        for j, pose in enumerate(poses):
            i = start + j
            odometry[i] = pose
            key = bool(usable[i]) and pick_key(pose)
            picked = pick_anchor(pose)
            if key:
                keyframes.append(i)
                for row in waiting:
                    a, k = index[row], keyframes[before[row]]
                    pose_after[row] = refine(i, a)
                    share[row] = (a - k) / max(i - k, 1)
                    refine.done(a)
                waiting = []
            elif picked and keyframes and i > keyframes[0]:
                index.append(i)
                before.append(len(keyframes) - 1)
                pose_before.append(refine(keyframes[-1], i))
                waiting.append(len(index) - 1)
    if not np.array_equal(np.asarray(keyframes, dtype=np.int64), message[1]):
        back.put(None)
        return
    rows = len(index)
    after = np.full((rows, 3), np.nan)
    for row, pose in pose_after.items():
        after[row] = pose
    back.put(
        BetweenPlacements(
            np.asarray(index, dtype=np.int64),
            np.asarray(before, dtype=np.int64),
            np.asarray(pose_before, dtype=np.float64).reshape(rows, 3),
            after,
            np.array([share.get(row, 0.0) for row in range(rows)], dtype=np.float64),
        )
    )
    to.get()  # the parent's stop
