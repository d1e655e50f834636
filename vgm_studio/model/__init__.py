"""Stage 4: edge → p(success). Networks over VGMs, the RGB-plot baseline, the score baseline.

The public API is ``Validator``: load a checkpoint once, then predict for batches of edges.

    >>> from vgm_studio.model import Validator
    >>> validator = Validator.load("assets/models/vgmnet-default.pt")
    >>> p = validator.predict(edges)        # p(success) per edge
    >>> keep = validator.decide(p)          # at the threshold chosen on validation
"""

from vgm_studio.model.validator import Validator

__all__ = ["Validator"]
