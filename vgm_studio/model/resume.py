"""A training run's state after each epoch, so a run that is stopped picks up where it was.

Slow networks on a CPU (the paper's VGM-Net takes tens of minutes an epoch) must survive a
killed shell or a closed laptop: ``fit_network`` writes this state after every epoch and, when
told the same file again, continues from the epoch after the last one written. What is saved
is all that decides the rest of the run (weights, optimiser moments, the schedule's step, both
random generators, the early-stopping bookkeeping), so a resumed run ends with the weights an
uninterrupted one would have.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vgm_studio.atomic import atomic_path
from vgm_studio.errors import InputError


@dataclass
class RunState:
    """Everything a run needs to go on after ``epoch``.

    Attributes:
        key: Fingerprint of the recipe and the rows: a state from another run is not used.
        epoch: Epochs done.
        best_loss: Best validation loss so far.
        stale: Epochs since it improved.
        history: One record per epoch done.
        best: The best epoch's weights.
        net: The weights now.
        optimiser: The optimiser's state.
        schedule: The learning-rate schedule's state.
        draws: The numpy generator's state (draws and rotations).
        torch_rng: torch's CPU generator state (dropout).
    """

    key: str
    epoch: int
    best_loss: float
    stale: int
    history: list[dict[str, float]]
    best: dict[str, torch.Tensor]
    net: dict[str, torch.Tensor]
    optimiser: dict[str, Any]
    schedule: dict[str, Any]
    draws: dict[str, Any]
    torch_rng: torch.Tensor


def run_key(recipe: object, network: str, *arrays: np.ndarray) -> str:
    """A fingerprint of a recipe (a dataclass), the network (its input and layer shapes, as
    text) and the rows it trains on."""
    digest = hashlib.sha256(repr(sorted(asdict(recipe).items())).encode())  # type: ignore[call-overload]
    digest.update(network.encode())
    for array in arrays:
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


def save_run(path: Path, state: RunState) -> None:
    """Writes ``state`` whole or not at all (a kill mid-write leaves the last one)."""
    with atomic_path(path) as tmp:
        torch.save(asdict(state), tmp)


def load_run(path: Path, key: str) -> RunState | None:
    """The state at ``path`` if it belongs to the run with ``key``; None when there is none.

    Raises:
        InputError: The file is there but is not a readable run state.
    """
    if not path.exists():
        return None
    try:
        raw = torch.load(path, map_location="cpu", weights_only=True)
        state = RunState(**raw)
    except Exception as exc:  # any unreadable file gets the same message
        raise InputError(
            path, f"not a training run state ({type(exc).__name__}); delete it to start over"
        ) from None
    return state if state.key == key else None
