"""The no-learning baseline: a threshold on the matcher's own figures.

Like Cartographer's ``min_score`` or Karto's minimum response, but with the threshold fit on
the training edges: a logistic model of p(success) from the inlier ratio and the log residual,
class-balanced, decided at p = 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class ScoreModel:
    """p(success) = σ(w · standardised figures + b)."""

    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    bias: float

    @classmethod
    def fit(cls, x: NDArray[np.float64], y: NDArray[np.bool_], l2: float = 1e-3) -> ScoreModel:
        """Fits class-balanced logistic regression by Newton's method."""
        mean = x.mean(axis=0)
        scale = np.where(x.std(axis=0) > 0, x.std(axis=0), 1.0)
        z = np.column_stack([(x - mean) / scale, np.ones(len(x))])
        target = y.astype(np.float64)
        pos = max(int(y.sum()), 1)
        neg = max(int((~y).sum()), 1)
        sample_w = np.where(y, len(y) / (2 * pos), len(y) / (2 * neg))
        w = np.zeros(z.shape[1])
        for _ in range(50):
            p = 1.0 / (1.0 + np.exp(-z @ w))
            grad = z.T @ (sample_w * (p - target)) + l2 * w
            hess = (z * (sample_w * p * (1 - p))[:, None]).T @ z + l2 * np.eye(len(w))
            step = np.linalg.solve(hess, grad)
            w -= step
            if np.abs(step).max() < 1e-9:
                break
        # Plain floats: checkpoints are loaded with weights_only, which refuses numpy scalars.
        return cls(
            tuple(map(float, mean)),
            tuple(map(float, scale)),
            tuple(map(float, w[:-1])),
            float(w[-1]),
        )

    def predict(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        z = (x - np.asarray(self.mean)) / np.asarray(self.scale)
        return np.asarray(1.0 / (1.0 + np.exp(-(z @ np.asarray(self.weights) + self.bias))))
