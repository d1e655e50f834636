"""``vgm-studio candidates``: a log's candidate edges, matched, labelled and written as JSONL."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from vgm_studio.datasets import ReadOptions
from vgm_studio.datasets.source import JoinOptions, read_source
from vgm_studio.matching.agreement import disagreement_warning, edges_agreement
from vgm_studio.matching.candidates import CandidateConfig, make_candidates
from vgm_studio.matching.edges import Edge, write_edges
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.reference_labels import LabelThresholds
from vgm_studio.services import Say, quiet

_LABELS = ("success", "failure", "ambiguous", "unlabelled")


@dataclass(frozen=True)
class EdgeRun:
    """Edges written, and how long making them took."""

    edges: list[Edge]
    seconds: float
    out: Path

    def table(self) -> str:
        """How many edges of each kind and label, after a line of totals and speed."""
        counts: Counter[tuple[str, str]] = Counter(
            (e.kind, e.label or "unlabelled") for e in self.edges
        )
        n, seconds = len(self.edges), self.seconds
        lines = [
            f"wrote {n} edges to {self.out} in {seconds:.1f} s ({n / max(seconds, 1e-9):.0f} "
            "edges/s)",
            f"{'kind':<12}" + "".join(f"{lab:>12}" for lab in _LABELS),
        ]
        for kind in ("sequential", "loop"):
            if any(k == kind for k, _ in counts):
                lines.append(
                    f"{kind:<12}" + "".join(f"{counts[(kind, lab)]:>12}" for lab in _LABELS)
                )
        torn = sum(bool(e.match.get("reference_check", {}).get("contradicted")) for e in self.edges)
        if torn:
            lines.append(
                f"{torn} of the ambiguous would be failures, but the scans contradict their "
                "reference (--no-check-reference keeps them failures)"
            )
        return "\n".join(lines)


def make_edge_file(
    log: Path,
    out: Path,
    read: ReadOptions,
    reference: Path | None = None,
    join: JoinOptions | None = None,
    config: CandidateConfig | None = None,
    thresholds: LabelThresholds | None = None,
    warn: Say = quiet,
) -> EdgeRun:
    """Reads a log and its reference, makes its candidate edges and writes them to ``out``.

    Raises:
        InputError: The log or reference cannot be read, or ``out`` cannot be written.
    """
    config = config or CandidateConfig()
    source = read_source(
        log, read, reference, join, max_loops=config.max_loops if config.loops else None
    )
    for line in source.warnings:
        warn(line)
    start = time.perf_counter()
    edges = make_candidates(
        source.log, ScanMatcher(), config, thresholds, source.relations, source.params
    )
    seconds = time.perf_counter() - start
    write_edges(out, edges)
    disagreement = disagreement_warning(source.log, edges_agreement(source.log, edges))
    if disagreement is not None:
        warn(disagreement)
    return EdgeRun(edges, seconds, out)
