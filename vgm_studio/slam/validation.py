"""Edge validation: which matched pairs may enter the pose graph.

``none`` keeps all; the model validators ask a trained checkpoint for p(success) in batches;
``reference`` keeps the edges whose estimate lands on the reference relative pose. A model
trained on local maps (``--context``) reads each keyframe with its neighbour scans from the
log, placed by the run's own odometry (``LocalMaps``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.errors import InputError
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.matcher import MatchResult
from vgm_studio.matching.reference_labels import reference_label
from vgm_studio.model.context import Context, LocalMapper, Placements
from vgm_studio.model.features import sample_from_scans
from vgm_studio.model.registry import VALIDATOR_MODELS
from vgm_studio.slam.config import ValidationConfig
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.odometry import Judge
from vgm_studio.slam.placing import PlacingAhead

if TYPE_CHECKING:
    from vgm_studio.model.validator import Validator


@dataclass(frozen=True)
class LocalMaps:
    """Where a keyframe's neighbours come from, for a model that reads local maps.

    Attributes:
        scans: Every scan of the log.
        poses: (N, 3) every scan's pose from the run's odometry: which scans are a
            keyframe's neighbours, and where each neighbour's match to it starts.
        keyframes: Each keyframe's index in the log.
        ahead: Place the keyframes' neighbours in a worker process ahead of need
            (``slam/placing.py``): the same maps, sooner where a core is free.
    """

    scans: Sequence[Scan]
    poses: NDArray[np.float64]
    keyframes: Sequence[int] | NDArray[np.int64]
    ahead: bool = False


class EdgeValidator:
    """Sets ``p_success`` and ``kept`` of edges, a block at a time.

    Args:
        config: Which validator, its checkpoint and thresholds.
        scans: The keyframes' scans, by keyframe index.
        reference: (K, 3) reference poses of the keyframes (``reference`` only).
        local: Where keyframes' neighbours are found; needed by a model trained on local
            maps, unused by others.
        network_threads: torch's threads for the network until ``close`` (None: as they
            are). A SLAM run's other threads and workers hold the other cores, and torch's
            hand-offs between its own only cost CPU there (the same logits).

    Raises:
        InputError: The checkpoint is missing, unreadable or of another model, or
            ``reference`` was asked for without reference poses.
    """

    def __init__(
        self,
        config: ValidationConfig,
        scans: Sequence[Scan],
        reference: NDArray[np.float64] | None = None,
        local: LocalMaps | None = None,
        network_threads: int | None = None,
    ) -> None:
        self.config = config
        self._held = ExitStack()
        self._scans = scans
        self._reference = reference
        if config.validator == "reference" and reference is None:
            raise InputError(
                None,
                "--validator reference needs reference poses: a log with TRUEPOS or a "
                "corrected log, or --reference with one",
            )
        self._rate = _Rater(config) if config.validator in VALIDATOR_MODELS else None
        self.model: Validator | None = None if self._rate is None else self._rate.model
        # Set where the model reads local maps: each keyframe's, made once.
        self._maps: tuple[LocalMapper, Sequence[int] | NDArray[np.int64]] | None = None
        self._ahead: PlacingAhead | None = None
        if self.model is not None and self.model.context.neighbours:
            if local is None:
                self.model.require_single_scans("this run")
            else:
                mapper = LocalMapper(local.scans, local.poses, self.model.context)
                self._maps = (mapper, local.keyframes)
                if local.ahead:
                    self._ahead = PlacingAhead(mapper, local.keyframes)
        self.precision_cut: float | None = None
        if config.loop_precision is not None:
            if self.model is None:
                raise InputError(None, "--loop-precision needs a model validator")
            self.precision_cut = self.model.threshold_at_precision(config.loop_precision)
        if self.model is not None and network_threads is not None:
            self._held.enter_context(self.model.threads(network_threads))

    def __call__(self, edges: Sequence[SlamEdge]) -> None:
        if not edges:
            return
        name = self.config.validator
        if name == "none":
            for e in edges:
                e.kept = True
        elif name == "reference":
            assert self._reference is not None
            for e in edges:
                ref = se2.between(self._reference[e.a], self._reference[e.b])
                e.kept = reference_label(ref, e.estimate, self.config.thresholds) == "success"
                e.p_success = float(e.kept)
        else:
            assert self.model is not None and self._rate is not None
            p = self._rate((*self._sides(e), e.estimate, e.match) for e in edges)
            bar = self.loop_bar
            assert bar is not None  # a model gives one
            loop = np.array([e.kind == "loop" for e in edges])
            keep = self.model.decide(p) & (~loop | (p >= bar))
            for e, pe, k in zip(edges, p, keep, strict=True):
                e.p_success, e.kept = float(pe), bool(k)
        # The validator's own decision; only the consistency check (loops) may drop ``kept``
        # later. Sequential edges the validator rejects must say so too.
        for e in edges:
            e.validated = e.kept

    def _sides(self, edge: SlamEdge) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The points of the edge's two keyframes as the model reads them."""
        if self._maps is None:
            return self._scans[edge.a].points(), self._scans[edge.b].points()
        mapper, keyframes = self._maps
        if self._ahead is not None:
            self._ahead.collect()
        return mapper.sides(int(keyframes[edge.a]), int(keyframes[edge.b]), edge.estimate)

    def adopt(self, placed: Placements) -> None:
        """Neighbours' poses matched already, (centre, neighbour) → pose in the centre's frame
        (None: the match did not hold); the local maps match the rest on demand."""
        if self._maps is not None:
            self._maps[0].adopt(placed)

    @property
    def placing(self) -> tuple[Context, MatchConfig] | None:
        """How the local maps' neighbours are placed (``adopt`` takes placements made so
        elsewhere); None where the model reads single scans."""
        if self._maps is None:
            return None
        mapper = self._maps[0]
        return mapper.context, mapper.match_config

    def close(self) -> None:
        """Stops the worker that places neighbours ahead, if any, and gives torch back its
        thread count."""
        if self._ahead is not None:
            self._ahead.close()
        self._held.close()

    @property
    def context(self) -> Context:
        """The local maps the model reads (one scan a side without a model)."""
        return self.model.context if self.model is not None else Context()

    @property
    def threshold(self) -> float:
        return self.model.threshold if self.model is not None else math.nan

    @property
    def loop_bar(self) -> float | None:
        """The p(success) a loop needs (the highest of the model's threshold, the loop
        threshold and the precision cut); None where the validator gives no p to weigh."""
        if self.model is None:
            return None
        cuts = (self.config.loop_threshold, self.precision_cut)
        return max([self.model.threshold, *(c for c in cuts if c is not None)])


def check_loop_precision(config: ValidationConfig) -> None:
    """Refuses ``--loop-precision`` with a checkpoint that cannot serve it, before any work:
    the cut comes from the checkpoint's validation curve (``Validator.threshold_at_precision``).

    Raises:
        InputError: No model validator, or a checkpoint without a curve.
    """
    if config.loop_precision is None:
        return
    if config.validator not in VALIDATOR_MODELS:
        raise InputError(None, "--loop-precision needs a model validator")
    _load(config.model, config.validator).threshold_at_precision(config.loop_precision)


def pair_judge(config: ValidationConfig) -> Judge | None:
    """The model validator as a judge of matches of one scan against the one before it (the
    wheel-less odometry's candidates, ``slam/odometry.py``); None without a model.

    Raises:
        InputError: The checkpoint is missing, unreadable or of another model.
    """
    if config.validator not in VALIDATOR_MODELS:
        return None
    rate = _Rater(config)

    # A model trained on local maps reads the two scans alone here: the scans after them are
    # not placed yet. Sides without neighbours are among what it was trained on (a scan with
    # none within reach, the ends of a log).
    def judge(first: Scan, second: Scan, matches: Sequence[MatchResult]) -> NDArray[np.float64]:
        a, b = first.points(), second.points()
        return rate((a, b, m.estimate, m) for m in matches)

    return Judge(judge, rate.model.threshold)


Pair = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], MatchResult]
"""A matched pair as a model reads it: the two scans' points, the estimate, the match."""


class _Rater:
    """A model validator's p(success) of matched pairs, with its second look at the unsure.

    Raises:
        InputError: The checkpoint is missing, unreadable or of another model.
    """

    def __init__(self, config: ValidationConfig) -> None:
        self.model = _load(config.model, config.validator)
        from vgm_studio.model.validator import SecondLook  # torch is loaded by now

        self._look = SecondLook(turns=config.second_look)
        self._batch = config.batch_size

    def __call__(self, pairs: Iterable[Pair]) -> NDArray[np.float64]:
        samples = [sample_from_scans(a, b, est, match.figures()) for a, b, est, match in pairs]
        return np.asarray(self.model.predict_samples(samples, self._batch, self._look))


def _load(path: Path | None, validator: str) -> Validator:
    from vgm_studio.model.cache import shared_validator

    if path is None:
        raise InputError(None, f"--validator {validator} needs --model, a checkpoint of that model")
    model = shared_validator(path)
    if model.name not in VALIDATOR_MODELS[validator]:
        raise InputError(path, f"is a {model.name} checkpoint, not one for --validator {validator}")
    return model
