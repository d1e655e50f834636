"""The odometry made in a spawned process while the front end takes its keyframes as they come.

kiss-icp is one thread, and on Intel its 13 s were a fifth of the run with the front end
waiting for all of it. Here a worker makes the odometry and sends it back a chunk at a time;
the run picks its keyframes from each chunk as it would from the whole (``KeyframePicker``)
and the front end takes a block as soon as the block's keyframes are *ready*: their poses
known, and the poses of every scan a local map may walk to from them (``ready``). The worker
also places each ready keyframe's neighbours for the local maps (``placing.placements``,
what ``PlacingAhead`` does after the odometry otherwise). The front end sees the same inputs
in the same blocks, so the run's edges and poses are those of a run that waited.

Only for a log with wheel odometry: without it, kiss-icp's lost steps are searched again and
judged by the validator (``odometry.Judge``), whose model lives in the run's process.
"""

from __future__ import annotations

import contextlib
import queue
import weakref
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.keyframes import KeyframePicker
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.model.context import Context, LocalMapper, Placements
from vgm_studio.processes import exit_with_parent, keep_for_good, start_worker
from vgm_studio.slam.odometry import scan_odometry
from vgm_studio.slam.placing import placements

# Poses sent back at a time: on Intel about 30 keyframes, a tenth of a second of odometry.
CHUNK = 256


def ready(keyframe: int, known: int, total: int, context: Context | None) -> bool:
    """Whether scan ``keyframe``'s local map can be made with the first ``known`` of ``total``
    poses: its walk (``model.context.walk``) reads at most ``context.scans`` scans past it."""
    if context is None or context.neighbours <= 0:
        return keyframe < known
    return known >= min(total, keyframe + context.scans + 1)


@dataclass(frozen=True)
class Chunk:
    """Poses of scans ``start`` to ``start + len(poses)``, and the neighbours of the keyframes
    that became ready with them, placed (empty without local maps)."""

    start: int
    poses: NDArray[np.float64]
    placed: Placements


class OdometryStream:
    """Runs ``scan_odometry`` in a worker and hands back its poses a chunk at a time.

    The worker starts on the scans at once; how it places the keyframes' neighbours comes
    later (``place_with``), once the run has loaded its model.

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
        self._proc, self._to, self._back = start_worker(_work, (list(scans), usable, keyframe_step))
        self._stop = weakref.finalize(self, _stop, self._proc)

    def place_with(self, local: tuple[Context, MatchConfig] | None) -> None:
        """The context and match settings the model's local maps are placed with; None where
        the model reads single scans (the chunks then carry no placements)."""
        self._to.put(local)

    def chunks(self) -> Iterator[Chunk]:
        """The chunks in order, to the last scan.

        Raises:
            RuntimeError: The worker died (killed, out of memory) before the last chunk.
        """
        try:
            while True:
                try:
                    message = self._back.get(timeout=1.0)
                except queue.Empty:
                    if not self._proc.is_alive():
                        raise RuntimeError("the odometry worker died") from None
                    continue
                if message is None:
                    return
                yield message
        finally:
            self._stop()


def _stop(proc: Any) -> None:
    # Once the last chunk is in the worker has nothing left to give: a run that ends early
    # (an error, a bad model) must not wait on it either.
    proc.terminate()
    proc.join(timeout=5.0)


class _Placer:
    """The worker's side of the local maps: each keyframe's neighbours placed once it is
    ``ready``, from when the run says how (``place_with``)."""

    def __init__(self, to: Any, scans: Sequence[Scan], poses: NDArray[np.float64]) -> None:
        self._to, self._scans, self._poses = to, scans, poses
        self._told = False
        self._mapper: LocalMapper | None = None
        self._context: Context | None = None
        self._waiting: deque[int] = deque()  # keyframes whose neighbours are not placed yet

    def add(self, keyframe: int) -> None:
        self._waiting.append(keyframe)

    def place(self, known: int, wait: bool) -> Placements:
        """The placements of the keyframes ready with ``known`` poses; none until the run has
        said how, unless ``wait``."""
        if not self._told:
            try:
                local = self._to.get() if wait else self._to.get_nowait()
            except queue.Empty:
                return {}
            self._told = True
            if local is not None:
                self._context = local[0]
                if local[0].neighbours > 0:
                    matcher = ScanMatcher(local[1])
                    self._mapper = LocalMapper(self._scans, self._poses, local[0], matcher)
        total = len(self._scans)
        centres = []
        while self._waiting and ready(self._waiting[0], known, total, self._context):
            centres.append(self._waiting.popleft())
        return placements(self._mapper, centres) if self._mapper is not None else {}


def _work(to: Any, back: Any) -> None:
    exit_with_parent()
    given: tuple[Sequence[Scan], NDArray[np.bool_], tuple[float, float]] = to.get()
    scans, usable, keyframe_step = given
    keep_for_good()  # the scans live as long as this worker
    total = len(scans)
    poses = np.full((total, 3), np.nan)
    placer = _Placer(to, scans, poses)
    pick = KeyframePicker(*keyframe_step)
    sent = 0

    def send(known: int) -> None:
        nonlocal sent
        placed = placer.place(known, wait=known == total)
        back.put(Chunk(sent, poses[sent:known].copy(), placed))
        sent = known

    def on_pose(i: int, pose: NDArray[np.float64]) -> None:
        poses[i] = pose
        if usable[i] and pick(pose):
            placer.add(i)
        if (i + 1) % CHUNK == 0:
            send(i + 1)

    scan_odometry(scans, progress=False, on_pose=on_pose)
    send(total)
    back.put(None)
    with contextlib.suppress(OSError, ValueError):
        back.close()
        back.join_thread()
