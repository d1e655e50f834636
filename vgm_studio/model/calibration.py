"""Where a trained model's cut is chosen: on real logs' validation edges.

Simulated worlds teach well (exact labels, as many corridors and doors as we like), but their
class mix and noise are ours, not a robot's; a model meets real logs. So the cut (the best
validation accuracy) is taken from the validation edges of real logs when each class has
enough of them there, and from all validation edges otherwise. The precision curve behind
``--loop-precision`` keeps every validation edge: a precision of 0.99 is estimated from the
failures above a cut, and the real logs alone hold about a third of them; on the eleven held-out
buildings the whole set's curve kept the same precision at a higher recall
(BENCHMARKS.md, "Which validation edges choose the cut"). The weights and early stopping
see every validation edge.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from vgm_studio.matching.edges import Edge
from vgm_studio.model.checkpoint import Checkpoint
from vgm_studio.model.fitting import judge
from vgm_studio.model.operating import precision_curve
from vgm_studio.simulation.simulate import is_simulated

# Each class needs this many real validation edges before the cut is chosen on them alone:
# with fewer, one edge moves the cut by more than the simulated ones bias it.
MIN_PER_CLASS = 30


def calibration_mask(edges: Sequence[Edge], labels: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Which of the validation ``edges`` choose the cut: the real logs' ones, or all."""
    simulated: dict[str, bool] = {}
    real = np.array(
        [not simulated.setdefault(e.log_path, is_simulated(e.log_path)) for e in edges], bool
    )
    enough = min(int(labels[real].sum()), int((~labels[real]).sum())) >= MIN_PER_CLASS
    return real if enough else np.ones(len(edges), dtype=bool)


def calibrate(
    checkpoint: Checkpoint,
    labels: NDArray[np.bool_],
    probs: NDArray[np.float64],
    real: NDArray[np.bool_],
) -> None:
    """Sets ``checkpoint``'s cut and its figures there from the ``real`` rows (a
    ``calibration_mask``) of the validation ``labels`` and ``probs``, and its precision curve
    from all of them."""
    checkpoint.threshold, checkpoint.metrics = judge(labels[real], probs[real])
    checkpoint.curve = precision_curve(labels, probs) if len(labels) else None
