"""Stage 4: edge → p(success). Networks over VGMs, the RGB-plot baseline, the score baseline.

The public API is ``Validator``: load a checkpoint once, then predict for batches of edges.
``registry`` lists the validators; ``checkpoint`` is what training writes.

    >>> from vgm_studio.model import Validator
    >>> validator = Validator.load("assets/models/vgmnet-default.pt")
    >>> p = validator.predict(edges)        # p(success) per edge
    >>> keep = validator.decide(p)          # at the threshold chosen on validation
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from vgm_studio.model.validator import Validator

__all__ = ["Validator"]


def __getattr__(name: str) -> Any:
    # ``Validator`` loads torch; the registry (read by the command line at start) must not.
    if name == "Validator":
        from vgm_studio.model.validator import Validator

        return Validator
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
