"""How far a team's annotators agree: Cohen's kappa per pair, on the edges both labelled."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from itertools import combinations


@dataclass(frozen=True)
class PairAgreement:
    """Two annotators compared on the edges both labelled.

    Attributes:
        first: One annotator (the alphabetically first of the two).
        second: The other.
        shared: Edges both labelled.
        agreed: Of those, edges with the same label.
        kappa: Cohen's kappa; None when it is undefined (no shared edge, or both gave one
            and the same label to every shared edge, so chance agreement is already 1).
    """

    first: str
    second: str
    shared: int
    agreed: int
    kappa: float | None


def cohen_kappa(pairs: list[tuple[str, str]]) -> float | None:
    """Cohen's kappa of two raters' labels on the same items; None when undefined."""
    n = len(pairs)
    if n == 0:
        return None
    observed = sum(a == b for a, b in pairs) / n
    first, second = Counter(a for a, _ in pairs), Counter(b for _, b in pairs)
    chance = sum(first[c] * second[c] for c in first) / (n * n)
    if chance >= 1.0:
        return None
    return (observed - chance) / (1.0 - chance)


def agreement(labels: dict[str, dict[str, str]]) -> list[PairAgreement]:
    """Every pair of annotators who share at least one edge, most shared edges first.

    Args:
        labels: edge_id → {annotator: label}, as ``LabelStore.label_map`` gives it.
    """
    shared: dict[tuple[str, str], list[tuple[str, str]]] = {}
    for votes in labels.values():
        for a, b in combinations(sorted(votes), 2):
            shared.setdefault((a, b), []).append((votes[a], votes[b]))
    out = [
        PairAgreement(a, b, len(pairs), sum(x == y for x, y in pairs), cohen_kappa(pairs))
        for (a, b), pairs in shared.items()
    ]
    return sorted(out, key=lambda p: (-p.shared, p.first, p.second))


def _printable(name: str, limit: int = 40) -> str:
    """A name as a terminal may show it: no escape sequences or other control characters."""
    clean = "".join(c if c.isprintable() else "?" for c in name)
    return clean if len(clean) <= limit else clean[: limit - 1] + "…"


def agreement_lines(pairs: list[PairAgreement]) -> list[str]:
    """The pairs as aligned text lines (a header first), for a terminal."""
    names = [f"{_printable(p.first)} · {_printable(p.second)}" for p in pairs]
    width = max([len(n) for n in names] + [len("annotators")])
    lines = [f"{'annotators':<{width}}  shared  agreed  Cohen's kappa"]
    for pair, name in zip(pairs, names, strict=True):
        kappa = "undefined" if pair.kappa is None else f"{pair.kappa:.3f}"
        lines.append(f"{name:<{width}}  {pair.shared:>6}  {pair.agreed:>6}  {kappa}")
    return lines
