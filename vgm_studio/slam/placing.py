"""Keyframes' neighbours placed in a second process, ahead of the front end's need for them.

A model that reads local maps needs each keyframe's neighbours matched to it
(``LocalMapper``): on Intel about 6,000 matches, 7 CPU s of Python that holds the GIL, so a
thread would not run beside the front end. A spawned process does, on a core the front end
leaves idle most of the time. It runs the same matches on the same inputs, so a map is the
same whichever process placed its neighbours; a placement it has not sent yet is made here.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.model.context import Context, LocalMapper, Placements, walk
from vgm_studio.processes import exit_with_parent, keep_for_good, spawn

# Keyframes a job places: small enough that the first arrive soon, large enough that the
# round trips cost little.
CHUNK = 64

_mapper: LocalMapper | None = None  # the worker process's own


def _start(inputs: Any) -> None:
    """Reads the mapper's inputs from the ``inputs`` queue: given as the process's arguments,
    the pool's start waited on the worker's imports (about a second on Intel)."""
    global _mapper
    exit_with_parent()
    given: tuple[Sequence[Scan], NDArray[np.float64], Context, MatchConfig] = inputs.get()
    scans, poses, context, config = given
    keep_for_good()  # the scans live as long as this worker
    _mapper = LocalMapper(scans, poses, context, ScanMatcher(config))


def placements(mapper: LocalMapper, centres: Sequence[int]) -> Placements:
    """Each centre's neighbours (its whole walk: what any pair may ask of it) placed."""
    return {
        (c, j): mapper.placed(c, j) for c in centres for j in walk(mapper.poses, c, mapper.context)
    }


def _place(centres: list[int]) -> Placements:
    assert _mapper is not None  # set by _start
    return placements(_mapper, centres)


class PlacingAhead:
    """Places the neighbours of ``centres`` in a worker process, in their order, and hands each
    batch to ``mapper`` once it is asked for a map and the batch is there.

    Args:
        mapper: The mapper that uses the placements.
        centres: The scans whose local maps will be asked for, in the order they will be.
    """

    def __init__(self, mapper: LocalMapper, centres: Sequence[int] | NDArray[np.int64]) -> None:
        self._mapper = mapper
        self._pool: ProcessPoolExecutor | None = None
        self._pending: deque[Future[Placements]] = deque()
        order = [int(c) for c in centres]
        try:
            context = spawn()
            # Kept while the worker lives: its thread writes the inputs as the worker starts.
            self._inputs: Any = context.Queue()
            self._inputs.cancel_join_thread()  # nor wait at exit for a worker that died
            self._pool = ProcessPoolExecutor(
                1, mp_context=context, initializer=_start, initargs=(self._inputs,)
            )
            for i in range(0, len(order), CHUNK):
                self._pending.append(self._pool.submit(_place, order[i : i + CHUNK]))
            self._inputs.put(
                (list(mapper.scans), np.asarray(mapper.poses), mapper.context, mapper.match_config)
            )
        except (OSError, RuntimeError):  # no processes here (no /dev/shm, a sandbox): no help
            self.close()

    def collect(self) -> None:
        """Hands the mapper every batch that has arrived, in order; a worker that failed is
        given up, and the mapper places the rest itself."""
        while self._pending and self._pending[0].done():
            try:
                self._mapper.adopt(self._pending.popleft().result())
            except Exception:  # a worker that could not start or died: nothing is lost
                self.close()

    def close(self) -> None:
        """Stops the worker; work not done is dropped."""
        self._pending.clear()
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
