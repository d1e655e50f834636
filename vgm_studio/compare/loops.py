"""Two runs' loops matched by the scans they join, and what changed between them.

Two runs of one log may pick other keyframes (a changed keyframe distance, a nudged
odometry), so a loop is known by the pair of log scans at its ends, not by keyframe index;
the same revisit found from keyframes a few scans apart is the same loop.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

from vgm_studio.compare.runs import Loop


@dataclass(frozen=True)
class LoopPair:
    """A loop in either run or both: ``base`` or ``new`` is None where that run has none."""

    base: Loop | None
    new: Loop | None

    @property
    def ends(self) -> tuple[int, int]:
        """The scans (or vertex ids) of the new run's loop where it has one, else the base's."""
        loop = self.new or self.base
        assert loop is not None  # a pair holds at least one loop
        return loop.a, loop.b

    @property
    def truth(self) -> str | None:
        """``false`` or ``right`` where either run can tell, else None."""
        return (self.new and self.new.truth) or (self.base and self.base.truth) or None

    @property
    def edge_id(self) -> str | None:
        """The studio's id of the loop: the new run's where it has one (the run CI shows)."""
        return (self.new and self.new.edge_id) or (self.base and self.base.edge_id) or None

    @property
    def kept_base(self) -> bool:
        return self.base is not None and self.base.kept

    @property
    def kept_new(self) -> bool:
        return self.new is not None and self.new.kept


@dataclass
class LoopChanges:
    """What changed in the loops from the base run to the new one.

    Attributes:
        matched: Loops in both runs.
        base_only: Loops only the base run proposed.
        new_only: Loops only the new run proposed.
        newly_kept: Kept by the new run, not by the base (rejected there, or not proposed).
        newly_dropped: Kept by the base run, not by the new one.
        flipped: In both runs with another decision (validator, consistency or kept).
        new_false: Wrong loops (``Loop.truth``) the new run keeps and the base did not.
        lost_right: Right loops the base run kept and the new one does not.
    """

    matched: int = 0
    base_only: int = 0
    new_only: int = 0
    newly_kept: list[LoopPair] = field(default_factory=list)
    newly_dropped: list[LoopPair] = field(default_factory=list)
    flipped: list[LoopPair] = field(default_factory=list)
    new_false: list[LoopPair] = field(default_factory=list)
    lost_right: list[LoopPair] = field(default_factory=list)


def match_loops(base: list[Loop], new: list[Loop], tolerance: int) -> list[LoopPair]:
    """Pairs each base loop with the new loop nearest in both ends, one to one.

    Args:
        base: The base run's loops.
        new: The new run's loops.
        tolerance: Most scans (or vertex ids) each end may differ by.

    Returns:
        Every loop once: matched pairs, then base-only, then new-only loops.
    """
    exact: dict[tuple[int, int], list[int]] = defaultdict(list)
    for j, loop in enumerate(new):
        exact[(loop.a, loop.b)].append(j)
    used_new: set[int] = set()
    pairs: dict[int, int] = {}
    # The same scans first: two runs that agree pay nothing for the nearer search.
    for i, loop in enumerate(base):
        free = [j for j in exact.get((loop.a, loop.b), ()) if j not in used_new]
        if free:
            pairs[i] = free[0]
            used_new.add(free[0])
    if tolerance > 0:
        _match_near(base, new, tolerance, pairs, used_new)
    out = [LoopPair(base[i], new[j]) for i, j in sorted(pairs.items())]
    out += [LoopPair(loop, None) for i, loop in enumerate(base) if i not in pairs]
    out += [LoopPair(None, loop) for j, loop in enumerate(new) if j not in used_new]
    return out


def _match_near(
    base: list[Loop],
    new: list[Loop],
    tolerance: int,
    pairs: dict[int, int],
    used_new: set[int],
) -> None:
    """Greedy matching of the loops left, nearest first, through cells of the tolerance."""
    cells: dict[tuple[int, int], list[int]] = defaultdict(list)
    for j, loop in enumerate(new):
        if j not in used_new:
            cells[(loop.a // tolerance, loop.b // tolerance)].append(j)
    options: list[tuple[int, int, int]] = []
    for i, loop in enumerate(base):
        if i in pairs:
            continue
        ca, cb = loop.a // tolerance, loop.b // tolerance
        for da in (-1, 0, 1):
            for db in (-1, 0, 1):
                for j in cells.get((ca + da, cb + db), ()):
                    gap = max(abs(new[j].a - loop.a), abs(new[j].b - loop.b))
                    if gap <= tolerance:
                        options.append((gap, i, j))
    for _gap, i, j in sorted(options):
        if i not in pairs and j not in used_new:
            pairs[i] = j
            used_new.add(j)


def _decided(loop: Loop) -> tuple[str, str, bool]:
    return loop.validator, loop.consistency, loop.kept


def changes(pairs: list[LoopPair]) -> LoopChanges:
    """Sorts matched loops into what a reviewer of a change asks about."""
    out = LoopChanges()
    for p in pairs:
        if p.base is not None and p.new is not None:
            out.matched += 1
            if _decided(p.base) != _decided(p.new):
                out.flipped.append(p)
        elif p.base is not None:
            out.base_only += 1
        else:
            out.new_only += 1
        if p.kept_new and not p.kept_base:
            out.newly_kept.append(p)
            # Judged by the loop that went in: a nearby base loop may be a different match.
            if p.new is not None and p.new.truth == "false":
                out.new_false.append(p)
        elif p.kept_base and not p.kept_new:
            out.newly_dropped.append(p)
            if p.base is not None and p.base.truth == "right":
                out.lost_right.append(p)
    # Injected loops first: a run told to keep none of them is the plainest failure.
    out.new_false.sort(key=lambda p: p.new is None or p.new.source != "injected")
    return out
