"""What a run is scored against: a relations file, or relations made from reference poses.

A log with reference poses (a GMapping-corrected log, a log with TRUEPOS, or one joined to
``--reference``) is scored without a relations file: relations are drawn from its reference
poses the way Kümmerle et al. (2009) drew theirs (see ``graph.metrics.reference_relations``).
"""

from __future__ import annotations

import dataclasses

from vgm_studio.datasets.relations import MatchedRelation
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.datasets.source import LogSource
from vgm_studio.graph.metrics import RelationSampling, reference_relations

# GMapping writes one NEFF line per update; its FLASER pose fields are then its corrected poses.
_GMAPPING_OUTPUT = "NEFF"


def with_own_reference(log: ScanLog) -> ScanLog:
    """A corrected log read with ``--poses odometry`` still scores against its corrected poses.

    Read that way its pose fields (the corrected poses) become the odometry and it has no
    reference; they are the reference all the same.
    """
    if log.reference_origin is not None or not log.message_counts.get(_GMAPPING_OUTPUT):
        return log
    scans = [dataclasses.replace(s, reference=s.odometry) for s in log.scans]
    return dataclasses.replace(log, scans=scans, reference_origin="pose fields")


def relations_from_reference(
    log: ScanLog, sampling: RelationSampling | None = None
) -> list[MatchedRelation] | None:
    """Relations drawn from the log's reference poses; None when it has none."""
    relations = reference_relations([s.reference for s in log.scans], sampling)
    return relations or None


def score_by_reference(source: LogSource) -> bool:
    """Reads a corrected log's pose fields as its reference (``with_own_reference``) and, where
    no relations file was given, scores by relations drawn from the reference poses; True
    when it drew them."""
    source.log = with_own_reference(source.log)
    if source.relations is not None:
        return False
    source.relations = relations_from_reference(source.log)
    return source.relations is not None
