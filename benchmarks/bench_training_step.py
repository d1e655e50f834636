"""Training speed of the bundled network: a step on the occupied cells beside the dense step.

Both paths train the same network on the same class-balanced, rotated draws of the model
benchmark's training edges (``edge_sets.py``), in turn, A B A B, on two cores; the table gives
each path's median seconds a step and the ratio. The loss of each first step is printed too:
the two are the same function, so it must agree to float rounding.

Run: python benchmarks/bench_training_step.py [--steps 20] [--pairs 3000]
"""

from __future__ import annotations

import argparse
import copy
import random
import time

import numpy as np
from _common import machine, pin_to_cores, table
from edge_sets import training_edges


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20, help="Timed steps per path and round.")
    parser.add_argument("--pairs", type=int, default=3000, help="Training pairs drawn from.")
    args = parser.parse_args()
    pin_to_cores(2)
    import torch

    from vgm_studio.matching.edges import read_edges
    from vgm_studio.model.features import load_samples
    from vgm_studio.model.fitting import Recipe
    from vgm_studio.model.registry import build_network
    from vgm_studio.model.validator import forward, input_spec, network_logits
    from vgm_studio.vgm import VGMParams

    edges = [e for path in training_edges() for e in read_edges(path)]
    edges = random.Random(0).sample(edges, min(args.pairs, len(edges)))
    samples = load_samples(edges, progress=False)
    labels = np.array([e.label == "success" for e in edges])
    recipe = Recipe()
    torch.manual_seed(0)
    cells_net, hyper = build_network("vgmnet", {"figures": True, "spread": True})
    dense_net = copy.deepcopy(cells_net)
    spec = input_spec("vgmnet", hyper, VGMParams())
    cpu = torch.device("cpu")

    def dense(net, batch, turns):
        return forward(net, *spec.tensors(batch, cpu, turns))

    def cells(net, batch, turns):
        return network_logits(net, spec, batch, cpu, turns)

    paths = {"dense (before)": (dense_net, dense), "occupied cells (now)": (cells_net, cells)}
    optimisers = {
        name: torch.optim.Adam(net.parameters(), lr=recipe.lr) for name, (net, _) in paths.items()
    }
    times: dict[str, list[float]] = {name: [] for name in paths}
    first: dict[str, float] = {}
    for round_ in range(2):
        for name, (net, logits_of) in paths.items():
            net.train()
            rng = np.random.default_rng(round_)  # the same draws for both paths
            torch.manual_seed(round_)  # and the same dropout masks
            for step in range(args.steps + 2):
                idx = rng.integers(0, len(samples), recipe.batch_size)
                turns = rng.uniform(0, 2 * np.pi, len(idx))
                start = time.perf_counter()
                logits = logits_of(net, [samples[i] for i in idx], turns)
                target = torch.from_numpy(labels[idx].astype(np.float32))
                loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, target)
                optimisers[name].zero_grad(set_to_none=True)
                loss.backward()
                optimisers[name].step()
                if step >= 2:  # the first steps set up oneDNN's kernels
                    times[name].append(time.perf_counter() - start)
                first.setdefault(name, float(loss.detach()))
    reference = float(np.median(times["dense (before)"]))
    rows = [
        [
            name,
            f"{np.median(t) * 1e3:.0f}",
            f"{recipe.batch_size / np.median(t):.0f}",
            f"{reference / np.median(t):.2f}×",
            f"{first[name]:.6f}",
        ]
        for name, t in times.items()
    ]
    print(
        f"# {len(samples)} training pairs, batch {recipe.batch_size}, {args.steps} × 2 steps a path"
    )
    print(f"# {machine()}")
    print(table(["training step", "ms/step", "pairs/s", "speed-up", "first loss"], rows))


if __name__ == "__main__":
    main()
