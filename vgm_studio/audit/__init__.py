"""Audit another SLAM's pose graph: every edge judged from its scans, the loops checked as a
group, the graph optimised again without the edges flagged (``vgm-studio audit``)."""

from vgm_studio.audit.config import AuditConfig, InjectConfig
from vgm_studio.audit.inputs import AuditInput, by_index, by_times, inline_input
from vgm_studio.audit.run import AuditResult, Verdict, run_audit

__all__ = [
    "AuditConfig",
    "AuditInput",
    "AuditResult",
    "InjectConfig",
    "Verdict",
    "by_index",
    "by_times",
    "inline_input",
    "run_audit",
]
