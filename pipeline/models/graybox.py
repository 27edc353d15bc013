"""Gray-box coupled model: an explicit model plus a data-driven regressor on its residual.

``nudot = base(X[:, base_columns]) + residual(X[:, residual_columns])``: the explicit model (Gertler-Hagen or
McFarland-Whitcomb, :mod:`pipeline.models.explicit`) carries the physics and extrapolates; the residual model
(by default a WDSE-SVR per output, :mod:`pipeline.models.svr`) learns what the structure misses (e.g. thrust lost to
propeller inflow, which the static tau of the feature store does not carry). Fit: the base on ``(X_base, y)``,
then the residual model on ``(X_res, y - base.predict(X_base))`` of the same rows.

Per output the residual is kept only where a CV says it helps (:func:`residual_verdict`: the residual search's
CV R² on the residual target, whole training trials held out under ``coupled.tuning_cv``, above a threshold, by
default 0, the score of a constant, by more than its standard error over the folds): elsewhere that output is the
base's prediction alone (``residual_outputs``, the outputs that keep it).

With the coupled study's columns ``X = [u v r tau_u tau_v tau_r T1 T2 T3]`` (the union of the explicit and the SVR
inputs, velocities first, as the simulate stage needs), ``base_columns = (0..5)``, ``residual_columns =
(0, 1, 2, 6, 7, 8)``.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, clone
from sklearn.utils.validation import check_is_fitted, validate_data

from pipeline.models.explicit import McFarlandWhitcomb
from pipeline.models.svr import WDSESVR, PerOutputRegressor

log = logging.getLogger(__name__)

__all__ = ["GrayBox", "kept_outputs", "paired_verdict", "residual_record", "residual_verdict", "residual_verdicts"]


def residual_verdict(cv_r2: float | None, threshold: float | None, se: float | None = None) -> tuple[bool, str]:
    """Whether a gray box keeps its residual on an output, and why, from the residual search's blocked-CV R² on
    the residual target and its standard error over the folds (``se``; None: 0): kept where the R² exceeds
    ``threshold`` by more than one SE (None: always kept, as is a residual with no score). R² 0 is a constant's;
    the SE margin is there because the search keeps the best of its candidates, and on a residual of white noise
    that best lands a little above 0 by chance (tests/models/test_graybox.py)."""
    if cv_r2 is None or threshold is None:
        return True, "kept" + ("" if cv_r2 is None else f" (CV R² {cv_r2:.3f})")
    se = 0.0 if se is None or not np.isfinite(se) else float(se)
    score = f"CV R² {cv_r2:.3f} ± {se:.3f}"
    if cv_r2 - se > threshold:
        return True, f"kept ({score})"
    return False, f"dropped ({score}: not above {threshold:g} by 1 SE)"


def residual_record(search: Any, threshold: float | None) -> dict[str, Any]:
    """A residual search's chosen hyperparameters (``search``: its :class:`pipeline.models.search.SearchResult`)
    with its blocked-CV R² on the residual (``residual_cv_r2``), that score's SE over the folds (``residual_cv_se``,
    the chosen candidate's in the search's trace) and the verdict they give (``residual``), as the tuned
    hyperparameters of one gray-box output record them."""
    score = float(search.best_score)
    chosen = [t for t in search.trace if t.get("score") == score]  # the chosen candidate's entry (last rung's)
    se = float(chosen[-1].get("se", 0.0)) if chosen else 0.0
    return {**search.best_params, "residual_cv_r2": score, "residual_cv_se": se,
            "residual": residual_verdict(score, threshold, se)[1]}


def _recorded_verdicts(hyper: dict[str, dict[str, Any]], outputs: Sequence[str], threshold: float | None
                       ) -> list[tuple[bool, str]]:
    """:func:`residual_verdict` of each output's recorded ``residual_cv_r2`` and ``residual_cv_se`` (absent, as in
    files tuned before the rule: kept)."""
    return [residual_verdict(hyper[out].get("residual_cv_r2"), threshold, hyper[out].get("residual_cv_se"))
            for out in outputs]


def residual_verdicts(hyper: dict[str, dict[str, Any]], outputs: Sequence[str], threshold: float | None
                      ) -> dict[str, str]:
    """Per output, the verdict's words for the tuned ``hyper``: the model card's ``residual``."""
    return {out: why for out, (_, why) in zip(outputs, _recorded_verdicts(hyper, outputs, threshold), strict=True)}


def kept_outputs(hyper: dict[str, dict[str, Any]], outputs: Sequence[str], threshold: float | None) -> list[int]:
    """The outputs (indices into ``outputs``) whose residual the tuned ``hyper`` keeps."""
    return [k for k, (kept, _) in enumerate(_recorded_verdicts(hyper, outputs, threshold)) if kept]


def paired_verdict(differences: Sequence[float], over: str = "folds") -> tuple[bool, str]:
    """Whether paired scores say the residual helps on an output, and their summary: ``differences`` the test R²
    of the gray box minus its base's, one per CV fold or held-out trial (``over`` names them). It helps where their
    mean is above 0 by more than its standard error. A tie does not: with one fold keeping its residual and the
    others dropping it, (a, 0, 0, 0, 0), the mean equals the SE, a / 5, and only rounding would decide."""
    d = np.asarray(differences, dtype=float)
    if d.size < 2 or not np.all(np.isfinite(d)):
        raise ValueError(f"a paired verdict needs two or more finite scores, got {d.tolist()}")
    mean, se = float(d.mean()), float(d.std(ddof=1) / np.sqrt(d.size))
    score = f"gray box − base, test R² {mean:+.2g} ± {se:.2g} over {d.size} {over}"
    return bool(mean > 0 and mean - se > 1e-9 * (abs(mean) + se)), score


class GrayBox(RegressorMixin, BaseEstimator):
    """Explicit ``base`` + ``residual`` regressor on the base's residual (3 outputs).

    ``base=None``: ``McFarlandWhitcomb()``; ``residual=None``: a default WDSE-SVR per kept output;
    ``base_columns=None``: the first 6 columns; ``residual_columns=None``: every column; ``residual_outputs``: the
    outputs (column indices of ``y``) whose residual is learnt, the others being the base's prediction alone (None:
    every output; a given ``residual`` then has one output per kept output, in order).
    Fitted: ``base_`` and ``residual_`` (fitted clones; ``residual_`` None where no output keeps a residual).
    """

    def __init__(self, base: Any = None, residual: Any = None, base_columns: Sequence[int] | None = None,
                 residual_columns: Sequence[int] | None = None,
                 residual_outputs: Sequence[int] | None = None) -> None:
        self.base = base
        self.residual = residual
        self.base_columns = base_columns
        self.residual_columns = residual_columns
        self.residual_outputs = residual_outputs

    def _kept(self, n_out: int) -> list[int]:
        kept = list(range(n_out)) if self.residual_outputs is None else [int(k) for k in self.residual_outputs]
        if any(not 0 <= k < n_out for k in kept) or len(set(kept)) != len(kept):
            raise ValueError(f"GrayBox: residual_outputs {kept} not distinct outputs of y's {n_out}")
        return kept

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
        resid2 = resid.reshape(-1, 1) if resid.ndim == 1 else resid
        self.kept_outputs_ = self._kept(resid2.shape[1])
        self.residual_ = None
        if self.kept_outputs_:
            residual = (PerOutputRegressor([WDSESVR() for _ in self.kept_outputs_]) if self.residual is None
                        else self.residual)
            self.residual_ = clone(residual).fit(X[:, res_cols], resid2[:, self.kept_outputs_])
        log.debug("GrayBox: base %s, residual RMS %s, residual kept on outputs %s", type(self.base_).__name__,
                  np.sqrt(np.mean(np.square(resid), axis=0)), self.kept_outputs_)
        return self

    def _add_residual(self, out: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """``out`` (the base's prediction) with the residual's added on the kept outputs; the others untouched."""
        out = np.array(out, dtype=float)
        view = out.reshape(len(out), -1)
        view[:, self.kept_outputs_] += np.asarray(residual, dtype=float).reshape(len(out), -1)
        return out

    def predict(self, X):
        check_is_fitted(self, "kept_outputs_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        base_cols, res_cols = self._columns(X.shape[1])
        out = self.base_.predict(X[:, base_cols])
        if self.residual_ is None:
            return out
        return self._add_residual(out, self.residual_.predict(X[:, res_cols]))

    def base_predict(self, X) -> np.ndarray:
        """The fitted base's prediction alone, on the same columns ``X`` as :meth:`predict` (every output)."""
        check_is_fitted(self, "base_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        return self.base_.predict(X[:, self._columns(X.shape[1])[0]])

    def narrowed(self, keep: Sequence[int]) -> GrayBox:
        """A copy of this fitted gray box whose residual stays only on the outputs of ``keep`` among
        ``kept_outputs_``; the others become the base's prediction alone, bit for bit. No refit: the base does not
        depend on the residual, and a :class:`PerOutputRegressor` residual fits each output on its own."""
        check_is_fitted(self, "kept_outputs_")
        wanted = {int(k) for k in keep}
        positions = [i for i, k in enumerate(self.kept_outputs_) if k in wanted]
        out = copy.copy(self)
        out.kept_outputs_ = [self.kept_outputs_[i] for i in positions]
        out.residual_outputs = tuple(out.kept_outputs_)
        if len(positions) == len(self.kept_outputs_):
            return out
        if not isinstance(self.residual_, PerOutputRegressor):
            raise TypeError(f"GrayBox.narrowed needs a PerOutputRegressor residual, not {type(self.residual_)}")
        out.residual = PerOutputRegressor([self.residual_.estimators[i] for i in positions])
        out.residual_ = None
        if positions:
            out.residual_ = copy.copy(self.residual_)
            out.residual_.estimators = out.residual.estimators
            out.residual_.estimators_ = [self.residual_.estimators_[i] for i in positions]
        return out

    def fast_predictor(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``predict`` of the fitted gray box as its parts' fast predictors (each part's ``fast_predictor()``:
        the explicit base's arithmetic and the residual SVRs' numpy sums, :meth:`PerOutputRegressor.fast_predictor`)
        without scikit-learn's per-call checks, for rollouts; equal to ``predict`` to float rounding. None before
        ``fit`` or where either part offers none."""
        if not hasattr(self, "kept_outputs_"):
            return None
        names = ("base_", "residual_") if self.residual_ is not None else ("base_",)
        parts = [getattr(getattr(self, name, None), "fast_predictor", None) for name in names]
        if not all(callable(p) for p in parts):
            return None
        fast = [p() for p in parts]
        if any(f is None for f in fast):
            return None
        base, residual = fast[0], (fast[1] if len(fast) > 1 else None)
        base_cols, res_cols = self._columns(self.n_features_in_)

        def predict(X: np.ndarray) -> np.ndarray:
            X = np.asarray(X, dtype=float)
            out = base(X[:, base_cols])
            return out if residual is None else self._add_residual(out, residual(X[:, res_cols]))

        return predict

    def fit_intervals(self, X, y, **kwargs: Any) -> GrayBox:
        """``coefficient_intervals_``: the base model's (``fit_intervals``, for the card), where it has them."""
        check_is_fitted(self, "base_")
        if hasattr(self.base_, "fit_intervals"):
            X = np.asarray(X, dtype=float)
            base = self.base_.fit_intervals(X[:, self._columns(X.shape[1])[0]], y, **kwargs)
            self.coefficient_intervals_ = base.coefficient_intervals_
        return self

    def coefficients(self) -> dict[str, float]:
        """The base model's coefficients (for the model card)."""
        check_is_fitted(self, "base_")
        return self.base_.coefficients()
