"""Human labels: the workspace's SQLite label store, and labels in and out of it."""

from vgm_studio.labels.store import HUMAN_LABELS, LabelRecord, LabelStore

__all__ = ["HUMAN_LABELS", "LabelRecord", "LabelStore"]
