"""What each command does, as one call: the layer between the command line and the stages.

The command line (``tools/``) parses, calls one function here and prints what comes back;
these functions read, run the stages and write, and tell what they did through a ``say``
callback (progress, results) and a ``warn`` one (what went amiss but did not stop them).
"""

from collections.abc import Callable
from dataclasses import dataclass

Say = Callable[[str], None]


def quiet(_line: str) -> None:
    """A ``say`` or ``warn`` that tells nobody."""
    return None


@dataclass(frozen=True)
class Voice:
    """Who hears a service: ``say`` its results and progress, ``warn`` what went amiss."""

    say: Say = quiet
    warn: Say = quiet


__all__ = ["Say", "Voice", "quiet"]
