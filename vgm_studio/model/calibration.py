"""Where a trained model's cut and precision curve are chosen: on real logs' validation edges.

Simulated worlds teach well (exact labels, as many corridors and doors as we like), but their
class mix and noise are ours, not a robot's; a model meets real logs. So the cut (the best
validation accuracy) and the precision curve behind ``--loop-precision`` are taken from the
validation edges of real logs when each class has enough of them there, and from all
validation edges otherwise. The weights and early stopping still see every validation edge.
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
    checkpoint: Checkpoint, labels: NDArray[np.bool_], probs: NDArray[np.float64]
) -> None:
    """Sets ``checkpoint``'s cut, its figures there and its precision curve from ``labels``
    and ``probs`` (the calibration rows)."""
    checkpoint.threshold, checkpoint.metrics = judge(labels, probs)
    checkpoint.curve = precision_curve(labels, probs) if len(labels) else None
