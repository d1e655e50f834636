"""Leave-one-building-out folds: which edge files train and which test, never both.

Kept apart from the benchmark script (no imports of its shared code) so a test can check
the split on tiny files.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from vgm_studio.matching.edges import read_edges


@dataclass(frozen=True)
class Building:
    """One real building's edge files.

    Attributes:
        name: Short name (``intel``, ``acapulco``, ...).
        train: Its candidate edges (sequential and loops), used when it is not held out.
        test: Its loop candidates (the benchmark protocol), used when it is held out.
    """

    name: str
    train: Path
    test: Path


@dataclass(frozen=True)
class Fold:
    """One fold: a held-out building's loops against everything else."""

    held_out: str
    train: list[Path]
    test: Path


def make_folds(
    buildings: Sequence[Building], shared: Sequence[Path], held_out: Sequence[str] | None = None
) -> list[Fold]:
    """One fold per held-out building: train on the other buildings and ``shared`` (the
    simulated worlds), test on its loops.

    Args:
        buildings: Every real building.
        shared: Edge files trained on in every fold (never tested on).
        held_out: The buildings to hold out, in order (None: all).

    Raises:
        ValueError: An unknown building name, or a log found on both sides of a fold.
    """
    names = [b.name for b in buildings]
    unknown = sorted(set(held_out or ()) - set(names))
    if unknown:
        raise ValueError(f"unknown building(s) {', '.join(unknown)}; known: {', '.join(names)}")
    folds = []
    for name in held_out or names:
        test = next(b.test for b in buildings if b.name == name)
        train = [b.train for b in buildings if b.name != name] + list(shared)
        _check_disjoint(train, test)
        folds.append(Fold(name, train, test))
    return folds


def _check_disjoint(train: Sequence[Path], test: Path) -> None:
    """Refuses a fold whose test log (by content hash) also feeds its training set."""
    test_logs = _logs([test])
    both = test_logs & _logs(train)
    if both:
        raise ValueError(f"fold testing on {test.name} also trains on its log(s) {sorted(both)}")


def _logs(files: Sequence[Path]) -> set[str]:
    return {e.log_sha256 or e.log_path for f in files for e in read_edges(f)}
