"""Gray-box coupled model: an explicit model plus a data-driven regressor on its residual.

``nudot = base(X[:, base_columns]) + residual(X[:, residual_columns])``: the explicit model (Gertler-Hagen or
McFarland-Whitcomb, :mod:`pipeline.models.explicit`) carries the physics and extrapolates; the residual model
(by default a WDSE-SVR per output, :mod:`pipeline.models.svr`) learns what the structure misses (e.g. thrust lost to
propeller inflow, which the static tau of the feature store does not carry). Fit: the base on ``(X_base, y)``,
then the residual model on ``(X_res, y - base.predict(X_base))`` of the same rows.

With the coupled study's columns ``X = [u v r tau_u tau_v tau_r T1 T2 T3]`` (the union of the explicit and the SVR
inputs, velocities first, as the simulate stage needs), ``base_columns = (0..5)``, ``residual_columns =
(0, 1, 2, 6, 7, 8)``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, clone
from sklearn.utils.validation import check_is_fitted, validate_data

from pipeline.models.explicit import McFarlandWhitcomb
from pipeline.models.svr import WDSESVR, PerOutputRegressor

log = logging.getLogger(__name__)

__all__ = ["GrayBox"]


class GrayBox(RegressorMixin, BaseEstimator):
    """Explicit ``base`` + ``residual`` regressor on the base's residual (3 outputs).

    ``base=None``: ``McFarlandWhitcomb()``; ``residual=None``: a default WDSE-SVR per output;
    ``base_columns=None``: the first 6 columns; ``residual_columns=None``: every column.
    Fitted: ``base_`` and ``residual_`` (fitted clones).
    """

    def __init__(self, base: Any = None, residual: Any = None, base_columns: Sequence[int] | None = None,
                 residual_columns: Sequence[int] | None = None) -> None:
        self.base = base
        self.residual = residual
        self.base_columns = base_columns
        self.residual_columns = residual_columns

    def _columns(self, n_features: int) -> tuple[list[int], list[int]]:
        base = list(range(6)) if self.base_columns is None else [int(c) for c in self.base_columns]
        res = list(range(n_features)) if self.residual_columns is None else [int(c) for c in self.residual_columns]
        bad = [c for c in base + res if not 0 <= c < n_features]
        if bad:
            raise ValueError(f"GrayBox: column(s) {bad} outside X's {n_features} columns")
        return base, res

    def fit(self, X, y):
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        base_cols, res_cols = self._columns(X.shape[1])
        base = McFarlandWhitcomb() if self.base is None else self.base
        self.base_ = clone(base).fit(X[:, base_cols], y)
        resid = y - self.base_.predict(X[:, base_cols])
        n_out = 1 if resid.ndim == 1 else resid.shape[1]
        residual = PerOutputRegressor([WDSESVR() for _ in range(n_out)]) if self.residual is None else self.residual
        self.residual_ = clone(residual).fit(X[:, res_cols], resid)
        log.debug("GrayBox: base %s, residual RMS %s", type(self.base_).__name__,
                  np.sqrt(np.mean(np.square(resid), axis=0)))
        return self

    def predict(self, X):
        check_is_fitted(self, "residual_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        base_cols, res_cols = self._columns(X.shape[1])
        return self.base_.predict(X[:, base_cols]) + self.residual_.predict(X[:, res_cols])

    def fast_predictor(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``predict`` of the fitted gray box as its parts' fast predictors (each part's ``fast_predictor()``:
        the explicit base's arithmetic and the residual SVRs' numpy sums, :meth:`PerOutputRegressor.fast_predictor`)
        without scikit-learn's per-call checks, for rollouts; equal to ``predict`` to float rounding. None before
        ``fit`` or where either part offers none."""
        parts = [getattr(getattr(self, name, None), "fast_predictor", None) for name in ("base_", "residual_")]
        if not all(callable(p) for p in parts):
            return None
        base, residual = (p() for p in parts)
        if base is None or residual is None:
            return None
        base_cols, res_cols = self._columns(self.n_features_in_)

        def predict(X: np.ndarray) -> np.ndarray:
            X = np.asarray(X, dtype=float)
            return base(X[:, base_cols]) + residual(X[:, res_cols])

        return predict

    def coefficients(self) -> dict[str, float]:
        """The base model's coefficients (for the model card)."""
        check_is_fitted(self, "base_")
        return self.base_.coefficients()
