"""The model's p(success) for a workspace's edges, the ones on screen first.

Scoring every edge of a large log takes minutes (15,630 Intel edges: 2 to 4.5 minutes on a
laptop), and a panel that says "no model" all that while reads as if there were none. The
``Scorer`` therefore scores in batches in a background thread: before each batch it asks
which edges the tabs show and show next and scores those first, and it tells the studio what
it has so far and how far it got ("scoring 4,200 / 15,630"). When every edge is scored it
stores them at once, as ``workspace.predict_workspace`` does, under the same model key.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core.hashing import content_hash
from vgm_studio.labels.records import Predictions
from vgm_studio.labels.store import LabelStore
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.model.validator import Validator

Predict = Callable[[Sequence[Edge]], NDArray[np.float64]]
# Edges scored per pass through the rest of the queue: small enough that an edge a tab moves
# to waits a second or two, large enough that torch's batches stay efficient.
REST_BATCH = 128


def model_key(model: Path, precision: float | None) -> str:
    """The name the predictions are stored under (``workspace.predict_workspace``'s)."""
    key = f"{model.name}:{content_hash(model)[:12]}"
    return key + (f"@precision{precision:g}" if precision is not None else "")


class Scorer:
    """Scores a store's edges with a model in a background thread, wanted edges first.

    Args:
        store: The workspace's store; the scores are stored in it when all are made.
        model: The checkpoint to score with.
        wanted: Returns the edge ids to score before any other (the tabs' current and next
            edges); asked before every batch.
        show: Told the scores so far and (done, total), or None for progress once stored.
        precision: Cut the model's calls where its validation precision reaches this.
        predict: Scores edges (default: the model's ``Validator.predict``); for tests.
        batch: Edges per batch of the rest.
    """

    def __init__(
        self,
        store: LabelStore,
        model: Path,
        wanted: Callable[[], list[str]],
        show: Callable[[Predictions, tuple[int, int] | None], None],
        *,
        precision: float | None = None,
        predict: Predict | None = None,
        batch: int = REST_BATCH,
    ) -> None:
        self.store = store
        self.model = model
        self.precision = precision
        self._wanted = wanted
        self._show = show
        self._predict = predict
        self._batch = batch
        self.order: list[str] = []  # edge ids in the order they were scored
        self.error: Exception | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Scores in a daemon thread; returns at once."""
        self._thread = threading.Thread(target=self._run_safely, daemon=True, name="scoring")
        self._thread.start()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def _run_safely(self) -> None:
        try:
            self.run()
        except Exception as exc:  # a failed model must not take the labeling down
            self.error = exc

    def run(self) -> None:
        """Scores every edge (in this thread), stores the scores and shows them."""
        if self.store.versions.all():
            return  # the trainer's active version has its predictions already
        key = model_key(self.model, self.precision)
        current = self.store.predictions()
        if current.model == key and len(current.p) == self.store.count_edges():
            return
        validator = Validator.load(self.model)
        threshold = validator.threshold
        if self.precision is not None:
            threshold = validator.threshold_at_precision(self.precision)
        predict = self._predict or self._validator_predict(validator)
        edges = {e.edge_id: e for e in self.store.edges()}
        total, scores = len(edges), dict[str, float]()
        left = list(edges)  # in log order
        self._show(Predictions(None, threshold, {}), (0, total))
        while left:
            first = [e for e in self._wanted() if e in edges and e not in scores]
            batch = first or left[: self._batch]
            p = predict([edges[e] for e in batch])
            scores.update(zip(batch, (float(v) for v in p), strict=True))
            self.order.extend(batch)
            done = set(batch)
            left = [e for e in left if e not in done]
            self._show(Predictions(None, threshold, dict(scores)), (len(scores), total))
        self.store.set_predictions(key, scores, threshold)
        self._show(self.store.predictions(), None)

    @staticmethod
    def _validator_predict(validator: Validator) -> Predict:
        scans = EdgeScans()  # each log read once for all the batches

        def predict(batch: Sequence[Edge]) -> NDArray[np.float64]:
            return validator.predict(batch, scans=scans)

        return predict
