"""Typed configuration of an audit: how edges are judged, checked as a group and optimised."""

from __future__ import annotations

from dataclasses import dataclass, field

from vgm_studio.graph.config import GraphConfig
from vgm_studio.maps.config import MapConfig
from vgm_studio.slam.config import ConsistencyConfig, ValidationConfig


@dataclass(frozen=True)
class InjectConfig:
    """Deliberately wrong loops added to the graph before it is judged, so that the flags'
    recall and precision can be measured on any graph.

    Attributes:
        count: How many (0: none).
        seed: Seeds the pairs and their measurements.
        min_distance: The two vertices lie at least this far apart in the graph's own
            estimate, metres, so "b is where a was" is wrong by construction.
        min_gap: …and at least this many vertices apart.
    """

    count: int = 0
    seed: int = 0
    min_distance: float = 5.0
    min_gap: int = 20


@dataclass(frozen=True)
class AuditConfig:
    """Everything an audit depends on.

    Attributes:
        validation: The validator and its cuts (the bundled ``vgmnet`` by default); loops
            need ``loop_threshold`` as in ``slam``, sequential edges the model's threshold.
        consistency: The group check of the loops the validator passed (``slam.consistency``).
            The chain's estimate weighs as three loops, not the thousand of ``slam``: its
            covariances are the other SLAM's claims, often far surer than its drift (on the
            Killian Court graph whole revisits of 15 agreeing loops lay outside them), so a
            revisit's loops that agree with one another outvote it; a lone loop does not.
        graph: The noise floors added to the graph's own covariances in the group check, and
            the width of a flagged sequential edge in the cleaned graph.
        maps: The before and after maps.
        inject: False loops to add first.
        flag_below: A loop or a sequential edge whose p(success) is under this is a failure
            of its scans (None: the checkpoint's own threshold); a loop between it and the
            validation's loop cut is unsure, and the graph keeps it unless the group check
            rejects it.
        min_shared_view: A loop whose scans share less of their view than this
            (``judge.shared_view``) cannot be judged from them: unsure, whatever p says.
        support: A loop its scans fail is kept all the same where at least this many loops
            near it (``support_span`` vertices at both ends), kept by the group check, close
            a consistent cycle with it: the scans alone were not enough (a corridor seen
            from both ends), the revisit's other loops are.
        support_span: See ``support``.
        block: Loops are checked as a group a block of this many vertices at a time, in the
            order of their later vertex, and the ones kept closed into the estimate before the
            next block, as the front end of ``slam`` does.
    """

    validation: ValidationConfig = field(default_factory=ValidationConfig)
    consistency: ConsistencyConfig = field(
        default_factory=lambda: ConsistencyConfig(estimate_weight=3)
    )
    graph: GraphConfig = field(default_factory=GraphConfig)
    maps: MapConfig = field(default_factory=MapConfig)
    inject: InjectConfig = field(default_factory=InjectConfig)
    flag_below: float | None = None
    min_shared_view: float = 0.15
    support: int = 2
    support_span: int = 10
    block: int = 25
