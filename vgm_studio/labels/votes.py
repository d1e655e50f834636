"""What several annotators' labels of one edge add up to."""

from __future__ import annotations

from collections import Counter


def human_label(votes: dict[str, str]) -> str | None:
    """The majority label of an edge's annotators; None when unlabelled or tied."""
    if not votes:
        return None
    (top, n), *rest = Counter(votes.values()).most_common()
    return None if rest and rest[0][1] == n else top


def is_conflict(votes: dict[str, str]) -> bool:
    """Annotators gave the edge different labels."""
    return len(set(votes.values())) > 1
