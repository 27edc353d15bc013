"""Stage train's work for the coupled study (paper 000): :func:`train_stage` runs the blocked CV and the final
fits (:func:`pipeline.studies.coupled.evaluate_models`), and :func:`model_card` writes what each fitted model's card
says: inputs, hyperparameters, scores, interval, coefficients, a gray box's residual verdicts per output."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from pipeline.config import config_hash
from pipeline.config.params import EXPLICIT_MODELS, CoupledParams
from pipeline.errors import ModelError
from pipeline.models.graybox import residual_verdicts
from pipeline.studies.coupled import GRAYBOX_MODELS, evaluate_models, model_inputs
from pipeline.studies.tasks import SearchCache

__all__ = ["model_card", "train_stage"]


def model_card(model: str, result: dict[str, Any], params: CoupledParams, *, vehicle: str,
               hyper: dict[str, Any], data_lineage: Any, train_test: pd.DataFrame, test: pd.DataFrame
               ) -> dict[str, Any]:
    """The card of a fitted model (:func:`pipeline.models.card.save_model` adds versions and the file's hash)."""
    card = {"model": model, "study": "coupled 3-DOF (paper 000)", "vehicle": vehicle,
            "inputs": model_inputs(model, params), "outputs": params.outputs,
            "hyperparameters": hyper.get(model, {"solver": "tls"}), "seed": params.seed,
            "params_hash": config_hash(params), "data_lineage": data_lineage,
            "trained_on": {"split": "train_test", "rows": len(train_test),
                           "trials": sorted(train_test["trial"].unique())},
            "scores": {"cv": result["summary"], "final_check": result["final"],
                       "final_check_trials": sorted(test["trial"].unique())},
            "interval": result.get("interval")}  # per output; its coverage of the test trials in final_check
    if model not in EXPLICIT_MODELS:  # each SVR fitted on at most this many of the rows (evenly spaced in time)
        card["trained_on"]["svr_max_rows"] = params.svr_max_rows
    estimator = result["estimator"]
    if model in GRAYBOX_MODELS:  # per output: its residual kept or dropped, and the CV R² that decided
        card["residual"] = residual_verdicts(hyper[model], params.outputs, params.residual_min_cv_r2)
        if result.get("residual"):  # then the CV's folds, the gray box against its base (residual_check)
            card["residual_fold_check"] = result["residual"]
    if hasattr(estimator, "coefficients"):
        card["coefficients"] = estimator.coefficients()
    if getattr(estimator, "coefficient_intervals_", None):  # fossen and its gray box: block-bootstrap intervals
        card["coefficient_intervals"] = estimator.coefficient_intervals_
    if hasattr(estimator, "selected_terms_"):  # fossen: the backward elimination's rounds
        card["term_selection"] = estimator.selection_record(params.outputs)
    if getattr(estimator, "refine", False):  # coupled.explicit_refine
        cost = estimator.refine_cost_
        card["refinement"] = {"refined": bool(estimator.refined_),
                              "free_run_cost": None if cost is None else {"wtls": cost[0], "refined": cost[1]},
                              "horizon_s": params.refine_horizon_s}
    return card


def train_stage(train_test: pd.DataFrame, test: pd.DataFrame, tuning_keys: pd.DataFrame,
                hyper: dict[str, dict[str, Any]], params: CoupledParams, *, vehicle: str, data_lineage: Any,
                failures: dict[str, dict[str, str]],
                on_model: Callable[[str, dict[str, Any] | None, dict[str, Any] | None], None] | None = None,
                progress: Callable[..., Any] | None = None, rigid_body_mass: np.ndarray | None = None
                ) -> dict[str, Any]:
    """The train stage's work: :func:`evaluate_models` with the tuned ``hyper``, the nested folds' searches through
    one :class:`SearchCache` for the run. A model that fails is recorded in ``failures`` and the others go on;
    ``on_model(model, result, card)`` as each model finishes (its :func:`model_card`), ``(model, None, None)`` as
    one fails, so the stage writes it at once. Returns the results; a ModelError when every model failed."""

    def finished(model: str, res: dict[str, Any] | None) -> None:
        if on_model is not None:
            card = None if res is None else model_card(model, res, params, vehicle=vehicle, hyper=hyper,
                                                       data_lineage=data_lineage, train_test=train_test, test=test)
            on_model(model, res, card)

    results = evaluate_models(train_test, test, hyper, params, tuning_keys=tuning_keys[["trial", "t_ns"]],
                              n_jobs=params.n_jobs, failures=failures, on_model=finished, progress=progress,
                              cache=SearchCache(), rigid_body_mass=rigid_body_mass)
    if not results:
        raise ModelError("every coupled model failed: " + "; ".join(f"{m}: {e['reason']}"
                                                                   for m, e in failures.items()))
    return results
