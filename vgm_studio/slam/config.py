"""Typed configuration of a SLAM run: front end, validation, back end and maps."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from vgm_studio.graph.config import GraphConfig
from vgm_studio.maps.config import MapConfig
from vgm_studio.matching.reference_labels import LabelThresholds
from vgm_studio.model.registry import VALIDATOR_MODELS

# ``none`` keeps every edge, the model validators come from the model registry, ``reference``
# keeps the edges that land on the reference pose.
ValidatorName = str
VALIDATORS: tuple[str, ...] = ("none", *VALIDATOR_MODELS, "reference")


@dataclass(frozen=True)
class FrontEndConfig:
    """Keyframes, sequential edges and the loop-candidate search.

    Attributes:
        keyframe_distance: A new keyframe after this much travel, metres.
        keyframe_angle_deg: …or after this much rotation, degrees.
        loop_radius: Loop candidates lie within this distance in the current estimate, metres.
        loop_max_angle_deg: …and within this heading difference (a 180° scanner sees little of
            a place it faced away from), degrees.
        loop_min_gap: …and at least this many keyframes earlier.
        loops_per_keyframe: The nearest this many candidates of each keyframe are matched.
        block: Keyframes added between two updates of the running estimate: the validator
            and the incremental solver work on whole blocks.
        false_loops: Deliberately wrong loop closures to inject (robustness tests in the style
            of Sünderhauf and Protzel): pairs of keyframes at least ``false_loop_distance``
            apart, matched from a guess that claims they are at the same place.
        false_loop_distance: How far apart the keyframes of an injected loop are at least, in
            the odometry estimate, metres.
        seed: Seeds the injected loops.
    """

    keyframe_distance: float = 0.5
    keyframe_angle_deg: float = 20.0
    loop_radius: float = 3.0
    loop_max_angle_deg: float = 60.0
    loop_min_gap: int = 20
    loops_per_keyframe: int = 2
    block: int = 25
    false_loops: int = 0
    false_loop_distance: float = 5.0
    seed: int = 0


@dataclass(frozen=True)
class ValidationConfig:
    """Which edges go into the graph.

    Attributes:
        validator: ``none`` keeps every edge; ``vgmnet``, ``rgb-baseline`` and ``score`` ask a
            trained model (``model``); ``reference`` keeps edges whose estimate lands on the
            reference relative pose (the upper bound).
        model: Checkpoint of the model validators.
        loop_threshold: p(success) a loop edge needs (never below the checkpoint's own
            threshold); None: the checkpoint's. That threshold was chosen for accuracy, but a
            graph pays far more for one false loop than for a missed one, and loops are many.
        thresholds: What ``reference`` calls a success (only successes are kept).
        batch_size: Edges per forward pass of the model.
    """

    validator: ValidatorName = "vgmnet"
    model: Path | None = None
    loop_threshold: float | None = 0.8
    thresholds: LabelThresholds = field(default_factory=LabelThresholds)
    batch_size: int = 64


@dataclass(frozen=True)
class SlamConfig:
    """Everything a SLAM run depends on."""

    front_end: FrontEndConfig = field(default_factory=FrontEndConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    maps: MapConfig = field(default_factory=MapConfig)
