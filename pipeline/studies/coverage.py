"""Extrapolation and excitation diagnostics, before any model is trained: how far each test trial's model inputs
leave the rows the models are fitted on, and which inputs the training excited least.

Per test trial and input (:func:`input_coverage`):

- ``share_outside_range``: the share of the trial's samples outside the training rows' [min, max];
- ``share_outside_quantiles``: outside the training's [0.5 %, 99.5 %] quantiles (about 1 % for a trial drawn like
  the training: a softer, outlier-proof view of the same);
- ``max_excess`` and ``max_excess_sd``: the largest distance beyond [min, max], in the input's unit and in training
  SDs (None where the training held the input constant).

An input is **named** (``extrapolated``) when more than :data:`RANGE_SHARE` of the trial's samples lie outside the
training range and the largest excess exceeds :data:`MIN_EXCESS_SD` training SDs: a learned model (an RBF kernel
above all) has seen nothing there.

**The hull as a whole** (``hull``): each input inside its own range can still make a combination the training
never held (thrust to port while yawing to starboard). The measure is the Mahalanobis distance in the training
rows' standardized coordinates, against its own 99.5 % quantile over the training rows (empirical, so no Gaussian
assumption): ``share_beyond`` is the share of the trial's samples farther out, about 0.5 % for a trial like the
training, and the trial is outside the hull when it exceeds :data:`HULL_SHARE`. Chosen over a k-nearest-neighbour
distance because trial rows are serially correlated: a training sample's nearest neighbours are its own
neighbours in time, so the training's own k-NN distances say how fine the grid is, not how far the data reach,
and the threshold would need a time exclusion window and a k; the Mahalanobis distance has neither and costs one
pass. Its limit: it sees an ellipsoid, so a hole inside the training cloud (a ring of excitation) is not flagged.
Directions the training did not vary at all (an input that is a fixed linear function of others, τ of the
thrusts) get a variance floor of 1e-9 of the largest, so a trial that breaks that relation is far out. The
inputs **driving** an excursion are those whose removal lowers ``share_beyond`` by at least
:data:`DRIVER_DROP` of it (the distance recomputed, threshold too, without that input).

**Which predictions** (``extrapolated_share``, ``stretches``): a sample of a flagged trial is an extrapolation
when a named input lies outside its training range there or, for a trial outside the hull, the sample lies beyond
it; a trial that is not flagged has none (its ~0.5 % beyond the hull are the training's own tail). With the trial's
``t_ns`` the flagged samples are given as stretches of consecutive samples, in seconds from the trial's first
sample (the :data:`MAX_STRETCHES` longest, in time order).

**Excitation** (:func:`excitation`): per input, the training's 0.5–99.5 % quantile span over the test trials'
(pooled) span: below 1 the models are asked about a wider range than they learned; ``least_excited`` lists the
inputs below :data:`EXCITATION_RATIO`, lowest first, and ``lowest`` names the lowest (None without test trials).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from pipeline.errors import ModelError

log = logging.getLogger(__name__)

__all__ = ["QUANTILE", "RANGE_SHARE", "MIN_EXCESS_SD", "HULL_QUANTILE", "HULL_SHARE", "DRIVER_DROP",
           "EXCITATION_RATIO", "MAX_STRETCHES", "input_coverage", "hull_share", "stretches", "excitation",
           "study_coverage"]

QUANTILE = 0.005  # the per-input quantile band [0.5 %, 99.5 %]
RANGE_SHARE = 0.01  # an input is named when more of a trial's samples than this lie outside the training range
MIN_EXCESS_SD = 0.1  # ... and its largest excess beyond it is more than this many training SDs
HULL_QUANTILE = 0.995  # the training's own Mahalanobis quantile that bounds the hull
HULL_SHARE = 0.05  # outside the hull: more than this share beyond it (10x the 0.5 % of a trial like the training)
DRIVER_DROP = 0.5  # an input drives an excursion when leaving it out lowers share_beyond by this fraction of it
EXCITATION_RATIO = 0.8  # least excited: training span below this fraction of the test trials' span
MAX_STRETCHES = 10  # the longest stretches of extrapolated samples listed per trial
_EIGEN_FLOOR = 1e-9


def _values(frame: pd.DataFrame, columns: Sequence[str], what: str) -> np.ndarray:
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise ModelError(f"coverage: the {what} rows lack the input column(s) {missing}; they have "
                         f"{sorted(map(str, frame.columns))}")
    return frame[list(columns)].to_numpy(dtype=float)


def _finite_rows(x: np.ndarray) -> np.ndarray:
    return x[np.isfinite(x).all(axis=1)]


class _Hull:
    """The training rows' Mahalanobis distance (standardized, eigenvalue-floored) and its HULL_QUANTILE."""

    def __init__(self, train: np.ndarray) -> None:
        self.mean = train.mean(axis=0)
        sd = train.std(axis=0)
        self.scale = np.where(sd > 0, sd, 1.0)
        z = (train - self.mean) / self.scale
        cov = np.atleast_2d(np.cov(z, rowvar=False)) if len(z) > 1 else np.eye(train.shape[1])
        values, vectors = np.linalg.eigh(cov)
        floor = _EIGEN_FLOOR * max(float(values.max()), 1.0)
        self.whiten = vectors / np.sqrt(np.maximum(values, floor))
        self.limit = float(np.quantile(self.distance(train), HULL_QUANTILE))

    def distance(self, x: np.ndarray) -> np.ndarray:
        return np.sqrt((((x - self.mean) / self.scale @ self.whiten) ** 2).sum(axis=1))

    def share_beyond(self, x: np.ndarray) -> float:
        return float((self.distance(x) > self.limit).mean()) if len(x) else 0.0


def hull_share(train: np.ndarray, test: np.ndarray) -> float:
    """The share of ``test``'s rows beyond the training rows' own 99.5 % Mahalanobis quantile (module docstring)."""
    return _Hull(np.asarray(train, float)).share_beyond(np.asarray(test, float))


def _outside(tr: np.ndarray, te: np.ndarray) -> np.ndarray:
    """Per test sample: outside the training's [min, max]."""
    return (te < tr.min()) | (te > tr.max())


def _per_input(name: str, tr: np.ndarray, te: np.ndarray) -> dict[str, Any]:
    lo, hi = float(tr.min()), float(tr.max())
    qlo, qhi = (float(q) for q in np.quantile(tr, [QUANTILE, 1.0 - QUANTILE]))
    sd = float(tr.std())
    excess = np.maximum(np.maximum(te - hi, lo - te), 0.0)
    share = float(_outside(tr, te).mean())
    max_excess = float(excess.max())
    excess_sd = max_excess / sd if sd > 0 else None
    named = share > RANGE_SHARE and (excess_sd is None or excess_sd > MIN_EXCESS_SD)
    return {"input": name, "train_min": lo, "train_max": hi, "train_sd": sd, "test_min": float(te.min()),
            "test_max": float(te.max()), "share_outside_range": share,
            "share_outside_quantiles": float(((te < qlo) | (te > qhi)).mean()),
            "max_excess": max_excess, "max_excess_sd": excess_sd, "extrapolated": bool(named)}


def input_coverage(train: pd.DataFrame, test: pd.DataFrame, columns: Sequence[str], *,
                   time_column: str = "t_ns") -> dict[str, Any]:
    """How far one test trial's rows leave the training rows on ``columns``: per input and as a hull, and which of
    its samples are extrapolations (see the module docstring; ``stretches`` only where ``test`` has
    ``time_column``, int64 ns). Rows with a non-finite value in ``columns`` are left out (their count is given)."""
    columns = list(columns)
    if time_column in test.columns:
        test = test.sort_values(time_column, kind="mergesort")
    tr_all, te_all = _values(train, columns, "training"), _values(test, columns, "test")
    tr, te = _finite_rows(tr_all), _finite_rows(te_all)
    if len(tr) < 2:
        raise ModelError(f"coverage: {len(tr)} finite training row(s) on {columns}; need at least 2")
    out: dict[str, Any] = {"rows": len(te), "rows_dropped_nonfinite": len(te_all) - len(te)}
    if len(te) == 0:
        return {**out, "inputs": [], "extrapolated_inputs": [], "hull": None, "outside": False,
                "extrapolated_share": 0.0, "stretches": [], "stretches_total": 0}
    inputs = [_per_input(c, tr[:, j], te[:, j]) for j, c in enumerate(columns)]
    hull = _Hull(tr)
    share = hull.share_beyond(te)
    drivers: list[str] = []
    if share > HULL_SHARE and len(columns) > 1:
        for j, c in enumerate(columns):
            keep = [k for k in range(len(columns)) if k != j]
            if _Hull(tr[:, keep]).share_beyond(te[:, keep]) <= (1.0 - DRIVER_DROP) * share:
                drivers.append(c)
    named = [d["input"] for d in inputs if d["extrapolated"]]
    pairs = _pair_correlations(tr, te, columns, drivers)
    flagged = np.zeros(len(te), dtype=bool)
    for j, d in enumerate(inputs):
        if d["extrapolated"]:
            flagged |= _outside(tr[:, j], te[:, j])
    if share > HULL_SHARE:
        flagged |= hull.distance(te) > hull.limit
    runs, n_runs = [], 0
    if time_column in test.columns:
        times = test[time_column].to_numpy()
        runs, n_runs = stretches(flagged, times[np.isfinite(te_all).all(axis=1)], origin_ns=int(times[0]))
    out.update(inputs=inputs, extrapolated_inputs=named,
               hull={"measure": "mahalanobis", "quantile": HULL_QUANTILE, "train_limit": hull.limit,
                     "share_beyond": share, "outside": share > HULL_SHARE, "drivers": drivers,
                     "driver_correlations": pairs},
               outside=bool(named) or share > HULL_SHARE, extrapolated_share=float(flagged.mean()),
               stretches=runs, stretches_total=n_runs)
    return out


def stretches(flagged: np.ndarray, times_ns: np.ndarray, *, origin_ns: int | None = None
              ) -> tuple[list[dict[str, Any]], int]:
    """Runs of consecutive flagged samples (in time order) as ``{"start_s", "end_s", "samples"}``, in seconds from
    ``origin_ns`` (default: the first sample): the :data:`MAX_STRETCHES` longest (ties: the earlier), listed in
    time order; and how many runs there are in all."""
    flagged = np.asarray(flagged, dtype=bool)
    if not flagged.any():
        return [], 0
    edges = np.diff(np.concatenate([[0], flagged.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1  # inclusive sample indices
    lengths = ends - starts + 1
    keep = np.sort(np.argsort(-lengths, kind="stable")[:MAX_STRETCHES])
    t0 = int(times_ns[0]) if origin_ns is None else int(origin_ns)
    return [{"start_s": (int(times_ns[starts[k]]) - t0) / 1e9, "end_s": (int(times_ns[ends[k]]) - t0) / 1e9,
             "samples": int(lengths[k])} for k in keep], len(starts)


def _pair_correlations(tr: np.ndarray, te: np.ndarray, columns: list[str], drivers: list[str]
                       ) -> list[dict[str, Any]]:
    """Per pair of drivers, their correlation in training and in the trial: a combination never trained shows as
    a change of sign or size."""
    out = []
    idx = [columns.index(d) for d in drivers]
    for a in range(len(idx)):
        for b in range(a + 1, len(idx)):
            i, j = idx[a], idx[b]
            out.append({"inputs": [columns[i], columns[j]], "train_r": _corr(tr[:, i], tr[:, j]),
                        "test_r": _corr(te[:, i], te[:, j])})
    return out


def _corr(x: np.ndarray, y: np.ndarray) -> float | None:
    if len(x) < 2 or x.std() == 0 or y.std() == 0:
        return None
    return float(np.corrcoef(x, y)[0, 1])


def excitation(train: pd.DataFrame, tests: pd.DataFrame, columns: Sequence[str]) -> dict[str, Any]:
    """Per input, the training's 0.5–99.5 % quantile span and the (pooled) test trials' span and their ratio;
    ``least_excited``: the inputs whose ratio is below :data:`EXCITATION_RATIO`, lowest first; ``lowest``: the input
    with the lowest ratio (None without test rows)."""
    columns = list(columns)
    tr, te = _values(train, columns, "training"), _values(tests, columns, "test")
    per: dict[str, dict[str, Any]] = {}
    for j, c in enumerate(columns):
        a, b = tr[np.isfinite(tr[:, j]), j], te[np.isfinite(te[:, j]), j]
        span_tr = _span(a)
        span_te = _span(b)
        ratio = span_tr / span_te if span_tr is not None and span_te else None
        per[c] = {"train_span": span_tr, "test_span": span_te, "ratio": ratio}
    rated = sorted((v["ratio"], c) for c, v in per.items() if v["ratio"] is not None)
    return {"inputs": per, "least_excited": [c for r, c in rated if r < EXCITATION_RATIO],
            "lowest": rated[0][1] if rated else None}


def _span(x: np.ndarray) -> float | None:
    if len(x) == 0:
        return None
    lo, hi = np.quantile(x, [QUANTILE, 1.0 - QUANTILE])
    return float(hi - lo)


def study_coverage(train: pd.DataFrame, test: pd.DataFrame, inputs_by_model: Mapping[str, Sequence[str]], *,
                   trial_column: str = "trial") -> dict[str, Any]:
    """The document the tune stage writes: models with the same inputs form one group; per group the excitation and,
    per test trial (``test[trial_column]``), :func:`input_coverage`. ``flagged``: ``{trial: [inputs]}`` of the
    trials outside the training (named inputs and hull drivers, or ``[]`` where only the hull as a whole)."""
    groups: dict[tuple[str, ...], list[str]] = {}
    for model, cols in inputs_by_model.items():
        groups.setdefault(tuple(cols), []).append(model)
    trials = sorted(test[trial_column].astype(str).unique()) if len(test) else []
    doc: dict[str, Any] = {
        "training_rows": len(train),
        "training_trials": sorted(train[trial_column].astype(str).unique()) if trial_column in train else [],
        "test_trials": trials,
        "thresholds": {"quantile": QUANTILE, "range_share": RANGE_SHARE, "min_excess_sd": MIN_EXCESS_SD,
                       "hull_quantile": HULL_QUANTILE, "hull_share": HULL_SHARE, "driver_drop": DRIVER_DROP,
                       "excitation_ratio": EXCITATION_RATIO, "max_stretches": MAX_STRETCHES},
        "groups": [], "flagged": {}}
    for cols, models in groups.items():
        per_trial = {t: input_coverage(train, test[test[trial_column].astype(str) == t], cols) for t in trials}
        doc["groups"].append({"models": models, "inputs": list(cols),
                              "excitation": excitation(train, test, cols), "trials": per_trial})
        for t, res in per_trial.items():
            if res["outside"]:
                names = doc["flagged"].setdefault(t, [])
                for name in [*res["extrapolated_inputs"], *((res["hull"] or {}).get("drivers") or [])]:
                    if name not in names:
                        names.append(name)
                drivers = res["hull"]["drivers"]
                log.warning("coverage: test trial %s lies outside the training rows of %s: %s beyond their range, "
                            "%.1f %% of its samples outside the hull%s; %.1f %% of its predictions are "
                            "extrapolations", t, ", ".join(models), ", ".join(res["extrapolated_inputs"]) or "no input",
                            100 * res["hull"]["share_beyond"], f" (driven by {', '.join(drivers)})" if drivers else "",
                            100 * res["extrapolated_share"])
    return doc
