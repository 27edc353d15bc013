"""The coupled 3-DOF motion-model study (paper 000): tune -> blocked CV -> final check.

Pure functions over DataFrames (feature-store rows): :func:`tune_stage` and
:func:`pipeline.studies.training.train_stage` are the work of the stage shells ``stages/tune.py`` and
``stages/train.py``, which read and write; the tables and the figure are in :mod:`pipeline.report.coupled`.

Models: ``rbf_svr``, ``two_weights_svr``, ``wdse_svr`` (inputs ``coupled.inputs``, by default
``[u v r T1 T2 T3]``, the thrusters' static thrust, where the paper has their speeds ``n1 n2 n3``; one SVR per
output with its own hyperparameters) and ``gertler_hagen``, ``mcfarland_whitcomb`` (inputs ``[u v r tau_u tau_v
tau_r]``, all outputs at once, TLS), ``fossen`` (the same inputs; Fossen's 3-DOF model with the vehicle's M_RB,
:mod:`pipeline.models.fossen`), ``abkowitz`` (a ship's manoeuvring polynomial, :mod:`pipeline.models.manoeuvring`:
inputs ``[u v r]``, the thrust columns and the control-surface angles of ``coupled.inputs``). Outputs ``[udot vdot
rdot]``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection, Sequence
from typing import Any

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, RegressorMixin

from pipeline.config.params import EXPLICIT_MODELS, CoupledParams
from pipeline.config.rigid_body import RigidBody, rigid_body_mass
from pipeline.config.vehicle import THRUST_COLUMN
from pipeline.errors import ModelError
from pipeline.evaluate import (
    MODEL_FAILURES,
    check_no_leakage,
    guarded_folds,
    model_failure,
    search_folds,
    split_blocks,
    summarize_folds,
    trial_groups,
)
from pipeline.models.explicit import EXPLICIT_INPUTS, GertlerHagen, McFarlandWhitcomb
from pipeline.models.fossen import Fossen3DOF
from pipeline.models.graybox import GrayBox, kept_outputs, residual_record
from pipeline.models.manoeuvring import Abkowitz3DOF
from pipeline.models.search import SVR_MODELS, SearchSettings, make_svr
from pipeline.models.search_halving import fold_subset, search_rounds
from pipeline.models.svr import PerOutputRegressor
from pipeline.parallel import workers
from pipeline.rollout import grid_step_s
from pipeline.rounds import gather, run_inline
from pipeline.studies.intervals import held_out_trials, interval_coverage, oof_intervals, target_sd
from pipeline.studies.residual_check import fold_check
from pipeline.studies.tasks import SearchCache, fitted, train_tasks, tune_chains
from pipeline.vocabulary import NOISE_STD_COLUMNS

log = logging.getLogger(__name__)

__all__ = ["EXPLICIT_MODELS", "GRAYBOX_MODELS", "NestedTuned", "SearchCache", "noise_std_from", "rigid_body_uvr",
           "tune", "tune_local", "search_settings", "tuning_block", "tune_columns", "tune_stage",
           "build_model", "model_inputs", "evaluate_models", "run_study", "train_columns"]

#: gray-box models: explicit base (by name) + WDSE-SVR per output on its residual (pipeline/models/graybox.py)
GRAYBOX_MODELS = {"graybox": "mcfarland_whitcomb", "graybox_gh": "gertler_hagen", "graybox_fossen": "fossen",
                  "graybox_abkowitz": "abkowitz"}
_EXPLICIT_CLASSES = {"gertler_hagen": GertlerHagen, "mcfarland_whitcomb": McFarlandWhitcomb}


def rigid_body_uvr(rigid_body: RigidBody) -> np.ndarray:
    """The vehicle's rigid-body mass matrix M_RB over (u, v, r): the ``fossen`` model's known inertia."""
    return rigid_body_mass(rigid_body)[np.ix_([0, 1, 5], [0, 1, 5])]


def _abkowitz_inputs(params: CoupledParams) -> tuple[list[str], list[str]]:
    """``abkowitz``'s thrust and control-surface angle columns: the thrusters' thrust (``T_<thruster>_N``) of
    ``coupled.inputs``, else ``tau_u_N`` (a ship's propeller is its surge force); the actuator inputs that are
    angles (``_rad``: a control surface's ``angle_signal``)."""
    thrust = [c for c in params.inputs if THRUST_COLUMN.match(c)] or [EXPLICIT_INPUTS[3]]
    angles = [c for c in params.actuators() if c.endswith("_rad") and c not in thrust]
    return thrust, angles


def _base_inputs(model: str, params: CoupledParams) -> list[str]:
    """The columns an explicit model takes: ν and τ, or ``abkowitz``'s ν, thrust and angles."""
    if model == "abkowitz":
        thrust, angles = _abkowitz_inputs(params)
        return [*EXPLICIT_INPUTS[:3], *thrust, *angles]
    return list(EXPLICIT_INPUTS)


def _explicit(model: str, noise_std: Sequence[float] | None, frame: pd.DataFrame | None,
              rigid_body_mass: np.ndarray | None, params: CoupledParams, **refine: Any) -> Any:
    """An unfitted explicit model by name: ``fossen`` with the vehicle's M_RB and the rows' grid step (when
    ``frame`` has ``t_ns``; otherwise estimated by the model), ``abkowitz`` with its inputs' counts, the others by
    WTLS with ``refine``'s keywords."""
    if model == "abkowitz":
        thrust, angles = _abkowitz_inputs(params)
        return Abkowitz3DOF(n_thrust=len(thrust), n_surfaces=len(angles))
    if model == "fossen":
        dt = grid_step_s(frame["t_ns"].to_numpy()) if frame is not None and "t_ns" in frame.columns \
            and len(frame) > 1 else None
        m_rb = None if rigid_body_mass is None else np.asarray(rigid_body_mass, dtype=float).tolist()
        return Fossen3DOF(rigid_body_mass=m_rb, noise_std=noise_std, dt_s=dt)
    return _EXPLICIT_CLASSES[model](solver="wtls", noise_std=noise_std, **refine)


# -- models -----------------------------------------------------------------------------------------------

def model_inputs(model: str, params: CoupledParams) -> list[str]:
    """The feature columns a model takes: the SVRs ``params.inputs``, the explicit models ν and τ, a gray-box model
    the union (explicit inputs first, then the SVR inputs not among them: velocities stay first)."""
    if model in EXPLICIT_MODELS:
        return _base_inputs(model, params)
    if model in GRAYBOX_MODELS:
        base = _base_inputs(GRAYBOX_MODELS[model], params)
        return [*base, *(c for c in params.inputs if c not in base)]
    return list(params.inputs)


def noise_std_from(frame: pd.DataFrame | None) -> tuple[float, ...] | None:
    """The explicit models' ``noise_std`` from the smoother's SD columns (median over rows), τ left to the estimator
    (NaN); None when the table lacks any of :data:`NOISE_STD_COLUMNS`."""
    if frame is None or any(c not in frame.columns for c in NOISE_STD_COLUMNS):
        return None
    med = [float(np.nanmedian(frame[c].to_numpy(float))) for c in NOISE_STD_COLUMNS]
    if not all(np.isfinite(med)):
        return None
    return (*med[:3], float("nan"), float("nan"), float("nan"), *med[3:])


def build_model(model: str, hyper: dict[str, Any] | None, params: CoupledParams, *,
                train: pd.DataFrame | None = None, noise_std: Sequence[float] | None = None,
                rigid_body_mass: np.ndarray | None = None) -> Any:
    """An unfitted estimator predicting all outputs; ``hyper`` maps output -> SVR hyperparameters (a gray-box
    model's: its residual WDSE-SVR's). ``train`` (optional): the training rows, for the explicit models' noise SDs
    (:func:`noise_std_from`); ``noise_std`` (optional) gives them instead. ``rigid_body_mass``: the vehicle's M_RB
    over (u, v, r) (:func:`rigid_body_uvr`) for ``fossen`` (None: its inertia is identified whole)."""
    if noise_std is None:
        noise_std = noise_std_from(train)
    if model in EXPLICIT_MODELS:
        refine = {}
        if params.explicit_refine and model not in ("fossen", "abkowitz"):
            if train is None or "t_ns" not in train.columns or len(train) < 2:
                raise ModelError("explicit_refine needs the training rows' t_ns to know the grid step")
            refine = {"refine": True, "dt_s": grid_step_s(train["t_ns"].to_numpy()),
                      "refine_horizon_s": params.refine_horizon_s}
        return _explicit(model, noise_std, train, rigid_body_mass, params, **refine)
    known = list(SVR_MODELS) + list(EXPLICIT_MODELS) + list(GRAYBOX_MODELS)
    if model not in SVR_MODELS and model not in GRAYBOX_MODELS:
        raise ModelError(f"unknown model {model!r}; expected {known}")
    if not hyper or any(out not in hyper for out in params.outputs):
        raise ModelError(f"no tuned hyperparameters for {model!r} and every output {params.outputs}")
    if model in GRAYBOX_MODELS:
        cols = model_inputs(model, params)
        res_cols = [cols.index(c) for c in params.inputs]
        n_velocity = params.n_velocity_inputs()
        base = _explicit(GRAYBOX_MODELS[model], noise_std, train, rigid_body_mass, params)
        kept = kept_outputs(hyper, params.outputs, params.residual_min_cv_r2)  # where the CV says it helps
        residual = PerOutputRegressor([make_svr("wdse_svr", hyper[params.outputs[k]], n_velocity, params.c_rate,
                                                max_rows=params.svr_max_rows) for k in kept])
        n_base = len(_base_inputs(GRAYBOX_MODELS[model], params))
        return GrayBox(base=base, residual=residual, base_columns=tuple(range(n_base)),
                       residual_columns=tuple(res_cols), residual_outputs=tuple(kept))
    n_velocity = params.n_velocity_inputs()
    return PerOutputRegressor([make_svr(model, hyper[out], n_velocity, params.c_rate, max_rows=params.svr_max_rows)
                               for out in params.outputs])


def _check_columns(frame: pd.DataFrame, columns: Sequence[str], what: str) -> None:
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        thrust = [c for c in frame.columns if THRUST_COLUMN.match(c)]
        raise ModelError(f"{what}: feature table lacks columns {missing} named in params coupled.inputs / outputs; "
                         f"its thrusters' thrust columns are {thrust} (T_<thruster>_N, one per thruster of the "
                         f"vehicle config)")


def _search_rows(frame: pd.DataFrame, params: CoupledParams) -> tuple[pd.DataFrame, np.ndarray | None]:
    """A search's rows (at most ``max_samples``, evenly spaced) and their trials' codes for its folds
    (:func:`pipeline.evaluate.trial_groups` by ``tuning_cv``; None: blocked folds, or no ``trial`` column)."""
    if params.max_samples is not None and len(frame) > params.max_samples:
        frame = frame.iloc[np.unique(np.linspace(0, len(frame) - 1, params.max_samples).round().astype(int))]
    if "trial" not in frame.columns:
        return frame, None
    return frame, trial_groups(frame["trial"].to_numpy(), params.tuning_cv)


def search_settings(params: CoupledParams) -> SearchSettings:
    """The settings of every search of the study: ``params.search``'s method with its keys of ``params`` (each
    search serial: the study's parallelism is its tasks, :mod:`pipeline.studies.tasks`)."""
    return SearchSettings(method=params.search, n_folds=params.tuning_folds, n_jobs=1,
                          n_velocity=params.n_velocity_inputs(), max_evals=params.max_evals, seed=params.seed,
                          smooth_tolerance=params.smooth_tolerance, one_se=params.selection == "one_se",
                          screen_rows=params.screen_samples, screen_folds=params.screen_folds,
                          survivors=params.survivors, c_rate=params.c_rate, iter_cap_ratio=params.iter_cap_ratio)


def tune(tuning: pd.DataFrame, params: CoupledParams, *, n_jobs: int | None = 1, split: str = "tuning",
         progress: Callable[..., Any] | None = None, noise_std: Sequence[float] | None = None,
         cache: SearchCache | None = None, rigid_body_mass: np.ndarray | None = None
         ) -> tuple[dict[str, dict[str, dict[str, Any]]], dict[str, Any]]:
    """Search hyperparameters of every SVR model and output on one block: the tuning split (``split="tuning"``,
    the papers' protocol) or, with ``params.tuning == "nested"``, the train_test block (``split="train_test"``).
    Rows of any other split are refused.

    A gray-box model's residual WDSE-SVR is tuned on the residuals ``y - base.predict`` of its explicit base fitted
    on the (whole, time-ordered) tuning block, weighted by ``noise_std`` (default :func:`noise_std_from` the block:
    the same weights :func:`build_model` gives the base it is fitted with, or the residual it was tuned on is not
    the residual it learns); its search runs the same RBF -> 2-weights -> WDSE chain on the
    residual (the SVRs' optima are no warm start: the target differs). Returns ``(hyper, trace)``:
    ``hyper[model][output]`` = flat hyperparameters, ``trace[model][output]`` = the :class:`SearchResult` as a
    dict. ``progress(done, total, desc)`` (optional): each search's candidates, ``desc`` naming the search
    (``wdse_svr/udot_mps2 (3/9)``). ``cache`` (optional): the run's :class:`SearchCache` (default: one of this call).
    """
    if len(tuning) == 0:
        hint = (" (coupled.tuning: split tunes on the first features.tuning_fraction of each trial's time: raise "
                "it, or use coupled.tuning: nested)") if split == "tuning" else ""
        raise ModelError(f"{split} block is empty: nothing to tune on{hint}")
    if "split" in tuning.columns and set(tuning["split"].unique()) != {split}:
        raise ModelError(f"tune() on the {split} block got rows of split(s) {sorted(set(tuning['split']) - {split})}")
    _check_columns(tuning, [*params.inputs, *params.outputs], "tune")
    graybox = [m for m in GRAYBOX_MODELS if m in params.models]
    if graybox:
        _check_columns(tuning, sorted({c for m in graybox for c in _base_inputs(GRAYBOX_MODELS[m], params)}),
                       f"tune ({', '.join(graybox)})")
    data, groups = _search_rows(tuning, params)
    X = data[params.inputs].to_numpy(float)
    settings = search_settings(params)
    cache = cache if cache is not None else SearchCache()
    # simplest kernel first: each richer kernel's fast search is warm-started from the simpler one's optimum. The
    # chain runs even where the simpler kernels are not asked for (their results serve as warm starts only): a lone
    # WDSE search of 8 hyperparameters from the GP seed lands far from the chain's optimum (docs/benchmarks.md)
    wanted = [m for m in SVR_MODELS if m in params.models]
    order = SVR_MODELS[:SVR_MODELS.index(wanted[-1]) + 1] if wanted and params.search == "fast" else wanted
    # independent chains (tasks.tune_chains): per output the SVRs' chain, per gray box and output its residual's
    chains = [{"owner": None, "output": out, "label": out, "models": order, "names": [f"{m}/{out}" for m in order],
               "X": X, "y": data[out].to_numpy(float), "cache": cache, "groups": groups}
              for out in params.outputs] if order else []
    for model in graybox:
        base = _explicit(GRAYBOX_MODELS[model], noise_std if noise_std is not None else noise_std_from(tuning),
                         tuning, rigid_body_mass, params)
        cols = _base_inputs(GRAYBOX_MODELS[model], params)
        # the residual's own RBF -> 2-weights -> WDSE chain, as for the SVRs (the SVRs' optima are no warm start:
        # the target differs); each chain fits the base first, as a task (a Fossen base's fit takes seconds: off the
        # driver, and the three outputs' chains do not wait for one another)
        fit = (base, tuning[cols].to_numpy(float), tuning[params.outputs].to_numpy(float), data[cols].to_numpy(float),
               data[params.outputs].to_numpy(float))
        kernels = list(SVR_MODELS) if settings.method == "fast" else ["wdse_svr"]
        chains += [{"owner": model, "output": out, "label": f"{model}/{out}", "models": kernels, "X": X,
                    "groups": groups, "names": [*[None] * (len(kernels) - 1), f"{model}/{out}"],
                    "residual_of": (*fit, k), "cache": cache} for k, out in enumerate(params.outputs)]
    done = tune_chains(chains, settings, workers(n_jobs), progress)
    hyper: dict[str, dict[str, dict[str, Any]]] = {m: {} for m in [*order, *graybox]}
    trace: dict[str, Any] = {m: {} for m in [*order, *graybox]}
    for chain, results in zip(chains, done, strict=True):
        owner, out = chain["owner"], chain["output"]
        for model, res in zip(chain["models"], results, strict=True):
            if owner is not None and model != chain["models"][-1]:
                continue  # a gray box's residual keeps its WDSE; the simpler kernels were its warm starts
            name = owner or model
            log.info("tuned %s / %s: R2 %.4f with %d fits", name, out, res.best_score, res.n_fits)
            hyper[name][out] = res.best_params if owner is None else residual_record(res, params.residual_min_cv_r2)
            trace[name][out] = res.to_dict()
    for model in set(order) - set(wanted):  # warm starts only
        log.info("%s searched as the warm start of a richer kernel only", model)
        del hyper[model], trace[model]
    return hyper, trace


def tune_local(frame: pd.DataFrame, model: str, params: CoupledParams, start: dict[str, dict[str, Any]], *,
               noise_std: Sequence[float] | None = None, rigid_body_mass: np.ndarray | None = None
               ) -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """:func:`tune_local_rounds` run inline."""
    return run_inline(tune_local_rounds(frame, model, params, start, noise_std=noise_std,
                                        rigid_body_mass=rigid_body_mass))


def tune_local_rounds(frame: pd.DataFrame, model: str, params: CoupledParams, start: dict[str, dict[str, Any]], *,
                      noise_std: Sequence[float] | None = None, rigid_body_mass: np.ndarray | None = None) -> Any:
    """One model's hyperparameters re-tuned on ``frame`` (a CV fold's training rows) by a local search per output
    (:func:`pipeline.models.search.local_search`, at most ``params.fold_evals`` candidates) from ``start``
    (output -> the tune stage's hyperparameters). A gray-box model's residual is the one :func:`tune` forms: its
    base fitted on ``frame`` weighted by ``noise_std``. Returns ``(hyper, trace)`` as :func:`tune` for ``model``.
    It scores its candidates on the halving screen's folds (``params.screen_folds`` of the ``tuning_folds``, all
    when null): a few steps from an optimum chosen on all folds need no more than a screen does
    (docs/models.md, 'Successive halving'). A coroutine of :mod:`pipeline.rounds` (the outputs' searches side by
    side, :func:`pipeline.rounds.gather`)."""
    data, groups = _search_rows(frame, params)
    X = data[params.inputs].to_numpy(float)
    Y = data[params.outputs].to_numpy(float)
    svr = model
    if model in GRAYBOX_MODELS:
        base = _explicit(GRAYBOX_MODELS[model], noise_std if noise_std is not None else noise_std_from(frame),
                         frame, rigid_body_mass, params)
        cols = _base_inputs(GRAYBOX_MODELS[model], params)
        # a task, not the driver's work: a Fossen base selects its terms by free runs (seconds a fit)
        (base,) = yield [(fitted, (base, frame[cols].to_numpy(float), frame[params.outputs].to_numpy(float)))]
        Y = Y - base.predict(data[cols].to_numpy(float))
        svr = "wdse_svr"
    subset, n_folds = None, len(search_folds(len(X), params.tuning_folds, groups))  # the trials' may be fewer
    if params.screen_folds is not None and params.screen_folds < n_folds:
        subset = fold_subset(n_folds, params.screen_folds)
    searches = [search_rounds(svr, X, Y[:, k], "local", start=start[out], n_folds=params.tuning_folds, n_jobs=1,
                              n_velocity=params.n_velocity_inputs(), max_evals=params.fold_evals, fold_subset=subset,
                              iter_cap_ratio=params.iter_cap_ratio, groups=groups)
                for k, out in enumerate(params.outputs)]
    done = yield from gather(searches)  # the outputs' searches side by side: their rounds together
    return ({out: residual_record(res, params.residual_min_cv_r2) if model in GRAYBOX_MODELS else res.best_params
             for out, res in zip(params.outputs, done, strict=True)},
            {out: res.to_dict() for out, res in zip(params.outputs, done, strict=True)})


class NestedTuned(RegressorMixin, BaseEstimator):
    """A coupled SVR or gray-box model whose hyperparameters are searched (:func:`tune`) on the rows it is fitted
    on, then fitted there: the estimator of each CV fold under ``params.tuning == "nested"``, so that no fold's
    test block has a say in its hyperparameters. ``X`` holds :func:`model_inputs` columns in order, ``y`` the
    outputs. ``noise_std``: a gray-box base's errors-in-variables weights (:func:`noise_std_from` the rows the
    fold is cut from: ``X`` has no SD columns). ``cache``: the run's :class:`SearchCache`, shared by the folds (None:
    one per fit). ``start`` (output -> hyperparameters, the tune stage's): with the fast search and
    ``params.fold_evals`` set, the fold's search is :func:`tune_local` from it, not a whole :func:`tune`.
    ``rigid_body_mass``: a ``graybox_fossen`` base's M_RB over (u, v, r). ``groups`` (of :meth:`fit` and
    :meth:`tune_rounds`): each row's trial, for the search's folds (``coupled.tuning_cv``). ``preset``
    (``(hyperparameters, searches)``): the search :meth:`tune_rounds` ran on the same rows, fitted with no search of
    its own (the train stage runs a fold's search in rounds, then its fit as one task: :mod:`pipeline.studies.tasks`).
    Fitted: ``hyperparameters_`` (output -> params), ``search_`` (output -> the fold's search as a dict),
    ``estimator_``."""

    def __init__(self, model: str = "wdse_svr", params: CoupledParams | None = None,
                 noise_std: Sequence[float] | None = None, cache: SearchCache | None = None,
                 start: dict[str, dict[str, Any]] | None = None, rigid_body_mass: Any = None,
                 preset: tuple[dict[str, Any], dict[str, Any]] | None = None) -> None:
        self.model = model
        self.params = params
        self.noise_std = noise_std
        self.cache = cache
        self.start = start
        self.rigid_body_mass = rigid_body_mass
        self.preset = preset

    def tune_rounds(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None) -> Any:
        """The search :meth:`fit` runs on these rows, as a coroutine of :mod:`pipeline.rounds` returning
        ``(hyperparameters, searches)``: the local search from ``start`` in rounds, a whole search (no
        ``start``, or ``fold_evals`` null) inline."""
        params = (self.params or CoupledParams()).model_copy(update={"models": [self.model]})
        frame = pd.DataFrame(np.asarray(X, dtype=float), columns=model_inputs(self.model, params))
        frame[params.outputs] = np.asarray(y, dtype=float).reshape(len(frame), -1)
        if groups is not None:
            frame["trial"] = np.asarray(groups)
        if self.start is not None and params.fold_evals is not None and params.search == "fast":
            return (yield from tune_local_rounds(frame, self.model, params, self.start, noise_std=self.noise_std,
                                                 rigid_body_mass=self.rigid_body_mass))
        whole, searches = tune(frame, params, n_jobs=1, noise_std=self.noise_std, cache=self.cache,
                               rigid_body_mass=self.rigid_body_mass)
        return whole[self.model], searches[self.model]

    def fit(self, X: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None) -> NestedTuned:
        hyper, trace = self.preset if self.preset is not None else run_inline(self.tune_rounds(X, y, groups))
        self.hyperparameters_ = hyper
        self.search_ = trace
        self.estimator_ = self.built(hyper).fit(X, y)
        return self

    def built(self, hyper: dict[str, Any]) -> Any:
        """The unfitted estimator :meth:`fit` fits with these hyperparameters (:func:`build_model`)."""
        params = (self.params or CoupledParams()).model_copy(update={"models": [self.model]})
        return build_model(self.model, hyper, params, noise_std=self.noise_std, rigid_body_mass=self.rigid_body_mass)

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.estimator_.predict(X)


def evaluate_models(train_test: pd.DataFrame, test: pd.DataFrame, hyper: dict[str, dict[str, Any]],
                    params: CoupledParams, *, tuning_keys: pd.DataFrame | None = None, n_jobs: int | None = 1,
                    failures: dict[str, dict[str, str]] | None = None,
                    on_model: Callable[[str, dict[str, Any] | None], None] | None = None,
                    progress: Callable[..., Any] | None = None, cache: SearchCache | None = None,
                    rigid_body_mass: np.ndarray | None = None) -> dict[str, Any]:
    """Blocked CV on the train_test block and the final check on the test trial(s), per model.

    Returns ``{model: {"folds": [...], "summary": {...}, "final": {...} | None, "estimator": fitted,
    "interval": {output: {...}}}}``; the final estimator is fitted on the whole train_test block, the 90 %
    interval calibrated on the folds' out-of-fold residuals (:mod:`pipeline.studies.intervals`) and its share of
    the test trials' targets inside is in ``final[output]["interval_coverage"]``.

    A model's failure (:data:`pipeline.evaluate.MODEL_FAILURES`) names the model. With ``failures`` given it is
    logged, recorded there (``failures[model]`` = :func:`pipeline.evaluate.model_failure`) and the other models go
    on; without, it is raised as a ModelError. ``on_model(model, result or None)`` is called as each model
    finishes or fails (the stage writes that model's artifacts then, not after the whole study).
    ``progress(done, total, desc)`` (optional): CV folds and final fits of all models, as they finish.
    ``cache``: the run's :class:`SearchCache` for the nested folds' searches (default: one of this call).
    ``rigid_body_mass``: the vehicle's M_RB over (u, v, r), for ``fossen`` and its gray box (:func:`build_model`).
    """
    _check_columns(train_test, [*params.outputs, "trial", "t_ns"], "evaluate")
    cache = cache if cache is not None else SearchCache()
    keys = train_test[["trial", "t_ns"]]
    if len(test):
        check_no_leakage(train_test[["trial", "t_ns"]], test[["trial", "t_ns"]], tuning_keys)
    y = train_test[params.outputs].to_numpy(float)
    sd_train, sd_test = target_sd(train_test, params.outputs), target_sd(test, params.outputs)
    results: dict[str, Any] = {}
    specs: list[dict[str, Any]] = []
    for model in params.models:
        try:
            specs += _model_tasks(model, train_test, test, y, keys, hyper, params, tuning_keys, cache,
                                  rigid_body_mass)
        except MODEL_FAILURES as err:
            _failed(model, model_failure(model, err), failures, on_model)
    # every model's folds and final fit are independent tasks (pipeline.studies.tasks); a model is done, and
    # written, when its last task is
    remaining = {m: sum(s["model"] == m for s in specs) for m in params.models}
    done: dict[int, dict[str, Any]] = {}

    def task_done(index: int, res: dict[str, Any]) -> None:
        model = specs[index]["model"]
        done[index] = res
        remaining[model] -= 1
        if remaining[model]:
            return
        mine = [done[i] for i, s in enumerate(specs) if s["model"] == model]
        failed = next((r["failed"] for r in mine if "failed" in r), None)
        if failed is not None:
            _failed(model, failed, failures, on_model)
            return
        mine_specs = [s for s in specs if s["model"] == model]  # the folds' test rows: out-of-fold residuals
        check = (fold_check(mine_specs, mine, params.outputs, rule=params.residual_fold_check)  # against its base
                 if model in GRAYBOX_MODELS else {})
        folds = [r["fold"] for s, r in zip(mine_specs, mine, strict=True) if s["kind"] == "fold"]
        final = mine[-1]
        pairs = {k: [(s["test"], r["pred"]) for s, r in zip(mine_specs, mine, strict=True) if s["kind"] == k]
                 for k in ("fold", "trial")}
        interval = oof_intervals(pairs["fold"], y, params.outputs, sd_train, pairs["trial"])
        if final["final"] is not None:  # the final check: the test trials' targets inside, beside R²
            inside = interval_coverage(interval, mine_specs[-1]["y_test"], final["pred"], params.outputs, sd_test)
            for o in params.outputs:
                final["final"][o]["interval_coverage"] = inside[o]
        results[model] = {"folds": folds, "summary": summarize_folds(folds), "final": final["final"],
                          "estimator": final["estimator"], "interval": interval}
        if check:  # a gray box against its base on the folds, per output (model card, Table III)
            results[model]["residual"] = check
        log.info("%s: CV test R2 %s", model, {o: round(s["test_r2"]["mean"], 4)
                                             for o, s in results[model]["summary"].items()})
        if on_model is not None:
            on_model(model, results[model])

    train_tasks(specs, workers(n_jobs), progress=progress, on_task=task_done)
    return {m: results[m] for m in params.models if m in results}


def _failed(model: str, entry: dict[str, str], failures: dict[str, dict[str, str]] | None,
            on_model: Callable[[str, dict[str, Any] | None], None] | None) -> None:
    """A model's failure: raised as a ModelError without ``failures``; else logged, recorded, ``on_model``."""
    if failures is None:
        raise ModelError(f"model {model!r} failed ({entry['error']}): {entry['reason']}")
    log.error("model %s failed, the others go on: %s: %s", model, entry["error"], entry["reason"])
    failures[model] = entry
    if on_model is not None:
        on_model(model, None)


def _model_tasks(model: str, train_test: pd.DataFrame, test: pd.DataFrame, y: np.ndarray, keys: pd.DataFrame,
                 hyper: dict[str, dict[str, Any]], params: CoupledParams, tuning_keys: pd.DataFrame | None,
                 cache: SearchCache, rigid_body_mass: np.ndarray | None) -> list[dict[str, Any]]:
    """One model's tasks (:func:`pipeline.studies.tasks.train_tasks`): its blocked CV folds (each passed by the
    leakage guard first), then its final fit on the whole train_test block with the check on ``test``."""
    est = build_model(model, hyper.get(model), params, train=train_test, rigid_body_mass=rigid_body_mass)
    cols = model_inputs(model, params)
    _check_columns(train_test, cols, model)
    X = train_test[cols].to_numpy(float)
    # nested: each fold searches its own hyperparameters on its training blocks; the final model (below) uses the
    # tune stage's, searched on the whole train_test block it is fitted on
    nested = params.tuning == "nested" and model not in EXPLICIT_MODELS
    cv_est = NestedTuned(model, params, noise_std_from(train_test), cache, hyper.get(model),
                         rigid_body_mass) if nested else est
    folds = guarded_folds(len(X), params.folds, keys, tuning_keys)
    common = {"model": model, "X": X, "y": y, "outputs": params.outputs, "folds": len(folds),
              "groups": train_test["trial"].to_numpy()}  # a nested fold's search: its rows' trials
    tasks = [{**common, "kind": "fold", "fold": k, "estimator": cv_est, "train": train, "test": held}
             for k, (train, held) in enumerate(folds)]
    trials = held_out_trials(train_test["trial"].to_numpy(), params.folds)  # the interval's across-trial residuals
    tasks += [{**common, "kind": "trial", "fold": k, "folds": len(trials), "estimator": est, "train": train,
               "test": held} for k, (train, held) in enumerate(trials)]
    tasks.append({**common, "kind": "final", "estimator": est,
                  "X_test": test[cols].to_numpy(float) if len(test) else None,
                  "y_test": test[params.outputs].to_numpy(float) if len(test) else None})
    return tasks


def run_study(frame: pd.DataFrame, params: CoupledParams, *, n_jobs: int | None = 1,
              cache: SearchCache | None = None, rigid_body_mass: np.ndarray | None = None) -> dict[str, Any]:
    """Everything on one table with a ``split`` column: tune, CV, final check (no files), the searches of both
    through one :class:`SearchCache` (``cache``, default a new one). A model that fails is left out of ``results``
    and named in ``failed`` (``{model: {"error", "reason"}}``); the others stay."""
    cache = cache if cache is not None else SearchCache()
    blocks = split_blocks(frame)
    block = tuning_block(params)
    hyper, trace = tune(blocks[block], params, n_jobs=n_jobs, split=block, cache=cache,
                        rigid_body_mass=rigid_body_mass)
    failed: dict[str, dict[str, str]] = {}
    results = evaluate_models(blocks["train_test"], blocks["test"], hyper, params,
                              tuning_keys=blocks["tuning"][["trial", "t_ns"]], n_jobs=n_jobs, failures=failed,
                              cache=cache, rigid_body_mass=rigid_body_mass)
    return {"hyper": hyper, "trace": trace, "results": results, "failed": failed}


# -- the stages ----------------------------------------------------------------------------------------------

def tuning_block(params: CoupledParams) -> str:
    """The split the searches run on: ``train_test`` (``coupled.tuning: nested``) or ``tuning`` (``split``)."""
    return "train_test" if params.tuning == "nested" else "tuning"


def tune_columns(params: CoupledParams, available: Collection[str]) -> list[str]:
    """The feature-store columns the tune stage reads (of ``available``, the store's)."""
    cols = sorted({c for m in params.models for c in model_inputs(m, params)} | set(params.inputs)
                  | set(params.outputs))
    # a gray box's base is weighted by the smoother's SDs here as in train, so its residual is the one tuned on
    cols += [c for c in NOISE_STD_COLUMNS if c in available]
    if any(GRAYBOX_MODELS.get(m) == "fossen" for m in params.models):  # its free runs' grid step, as in train
        cols.append("t_ns")
    return [*cols, "split"]


def tune_stage(frame: pd.DataFrame, params: CoupledParams, *, vehicle: str,
               progress: Callable[..., Any] | None = None, rigid_body_mass: np.ndarray | None = None
               ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The tune stage's work: :func:`tune` on the rows of :func:`tuning_block` (``frame``), with one
    :class:`SearchCache` for the run. Returns ``(doc, trace)``: the document of hyperparameters.json (settings,
    block, ``hyperparameters[model][output]``) and each search's :class:`SearchResult` as a dict."""
    block = tuning_block(params)
    hyper, trace = tune(frame, params, n_jobs=params.n_jobs, split=block, progress=progress, cache=SearchCache(),
                        rigid_body_mass=rigid_body_mass)
    doc = {"vehicle": vehicle, "search": params.search, "seed": params.seed, "inputs": params.inputs,
           "outputs": params.outputs, "tuning": params.tuning, "tuned_on": block, "n_tuning_rows": len(frame),
           "max_samples": params.max_samples, "screen_samples": params.screen_samples,
           "screen_folds": params.screen_folds, "survivors": params.survivors,
           "fold_evals": params.fold_evals, "tuning_cv": params.tuning_cv,
           "search_folds": sorted({r["folds"] for per in trace.values() for r in per.values()}),
           "hyperparameters": hyper}
    return doc, trace


def train_columns(params: CoupledParams, available: Collection[str]) -> list[str]:
    """The feature-store columns the train stage reads (of ``available``, the store's)."""
    cols = ["t_ns", *sorted({c for m in params.models for c in model_inputs(m, params)} | set(params.outputs))]
    cols += [c for c in NOISE_STD_COLUMNS if c in available]  # the explicit models' errors-in-variables weights
    return cols
