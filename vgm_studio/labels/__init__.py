"""Human labels: the workspace's label store, annotators' votes, and labels in and out of it.

``LabelStore`` (SQLite) implements ``LabelRepository``; it hands out records, never SQL.
"""

from vgm_studio.labels.records import LabelRecord, ModelRecord, Predictions
from vgm_studio.labels.repository import LabelRepository
from vgm_studio.labels.store import HUMAN_LABELS, LabelStore

__all__ = [
    "HUMAN_LABELS",
    "LabelRecord",
    "LabelRepository",
    "LabelStore",
    "ModelRecord",
    "Predictions",
]
