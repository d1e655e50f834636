"""The one list of validators: each model's name, how it is built, what it reads, who trains it.

Every list of model names in the package (the command line's choices, the SLAM run's
validators, the checkpoints ``Validator.load`` accepts) is read from ``MODELS``. Adding a
validator is one module (its network, or a model fitted in closed form) and one entry here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from vgm_studio.errors import InputError

if TYPE_CHECKING:  # torch loads when a network is built, not when the command line starts
    from torch import nn

Reads = Literal["vgm", "rgb", "figures"]
Holds = Literal["network", "score"]
Built = tuple["nn.Module", dict[str, Any]]

BUNDLED_MODEL = Path(__file__).resolve().parents[2] / "assets" / "models" / "vgmnet-default.pt"


@dataclass(frozen=True)
class HyperFlags:
    """The command line's switches that shape a model's inputs (``vgm-studio train``)."""

    figures: bool = True
    occupancy: bool = False
    spread: bool | None = None
    inliers: bool = True
    blind: bool = True


@dataclass(frozen=True)
class ModelEntry:
    """One validator.

    Attributes:
        name: What the command line, checkpoints and the SLAM run call it.
        reads: Its input: ``vgm`` (the VGM's two channels), ``rgb`` (a plot of the pair) or
            ``figures`` (the matcher's numbers alone).
        holds: What its checkpoint carries: ``network`` weights, or a ``score`` model's
            fitted constants.
        build: Makes its network from hyper-parameters, returning it and the full
            hyper-parameters, defaults included (None: a model with no network).
        background: Whether the background trainer can train it.
        validator: The SLAM run's ``--validator`` that uses its checkpoints (None: none).
        hyper: Its hyper-parameters from the command line's switches.
    """

    name: str
    reads: Reads
    holds: Holds
    build: Callable[[dict[str, Any]], Built] | None
    background: bool
    validator: str | None
    hyper: Callable[[HyperFlags], dict[str, Any]]


def _built(network: type[nn.Module], config_type: type, hyper: dict[str, Any]) -> Built:
    hyper = dict(hyper)
    if "channels" in hyper:
        hyper["channels"] = tuple(hyper["channels"])
    config = config_type(**hyper)
    return network(config), asdict(config)


def _network(network: str, config: str) -> Callable[[dict[str, Any]], Built]:
    """A builder of ``networks.<network>`` from its ``networks.<config>`` dataclass."""

    def build(hyper: dict[str, Any]) -> Built:
        from vgm_studio.model import networks  # torch loads when a network is built

        return _built(getattr(networks, network), getattr(networks, config), hyper)

    return build


def _no_hyper(_flags: HyperFlags) -> dict[str, Any]:
    return {}


def _vgmnet_hyper(flags: HyperFlags) -> dict[str, Any]:
    return {
        "figures": flags.figures,
        "occupancy": flags.occupancy,
        "spread": flags.figures and flags.spread is not False,
        "inliers": flags.inliers,
        "blind": flags.figures and flags.blind,
    }


def _score_hyper(flags: HyperFlags) -> dict[str, Any]:
    return {"spread": bool(flags.spread)}


MODELS: tuple[ModelEntry, ...] = (
    ModelEntry(
        name="vgmnet",
        reads="vgm",
        holds="network",
        build=_network("VGMNet", "SparseConfig"),
        background=True,
        validator="vgmnet",
        hyper=_vgmnet_hyper,
    ),
    ModelEntry(
        name="vgmnet-paper",
        reads="vgm",
        holds="network",
        build=_network("VGMNetPaper", "PaperConfig"),
        background=False,
        validator="vgmnet",
        hyper=_no_hyper,
    ),
    ModelEntry(
        name="rgb-baseline",
        reads="rgb",
        holds="network",
        build=_network("RGBNet", "RGBConfig"),
        background=False,
        validator="rgb-baseline",
        hyper=_no_hyper,
    ),
    ModelEntry(
        name="score",
        reads="figures",
        holds="score",
        build=None,
        background=False,
        validator="score",
        hyper=_score_hyper,
    ),
)
MODEL_NAMES: tuple[str, ...] = tuple(m.name for m in MODELS)
# The SLAM run's model validators, each with the checkpoints it accepts.
VALIDATOR_MODELS: dict[str, tuple[str, ...]] = {
    v: tuple(m.name for m in MODELS if m.validator == v)
    for v in dict.fromkeys(m.validator for m in MODELS if m.validator is not None)
}


def entry(name: str) -> ModelEntry:
    """The registry's entry for ``name``.

    Raises:
        InputError: No model of that name.
    """
    for m in MODELS:
        if m.name == name:
            return m
    raise InputError(None, f"unknown model {name!r} (choose from {', '.join(MODEL_NAMES)})")


def default_hyper(name: str) -> dict[str, Any]:
    """``name``'s hyper-parameters as ``vgm-studio train`` sets them unasked: the bundled
    model's inputs, which the background trainer and the benchmarks' folds share."""
    return entry(name).hyper(HyperFlags())


def build_network(name: str, hyper: dict[str, Any] | None = None) -> Built:
    """Builds a model's network; returns it and its hyper-parameters as a plain dict."""
    build = entry(name).build
    if build is None:
        raise ValueError(f"{name} has no network")
    return build(dict(hyper or {}))
