"""The coupled study's 90 % prediction intervals: split conformal on the blocked CV's out-of-fold residuals,
locally weighted by the predicted value.

The train stage's blocked CV already predicts every train_test row with a model fitted without its block (the
folds' ``test_pred``). Per output, a row's spread s(p) = c_0 + c_1 |p| (p: its out-of-fold prediction) is fitted
to the |residuals| by non-negative least squares, its score is ``|residual| / s(p)`` and ``q`` is the
``ceil((n + 1) 0.9)``-th smallest score (:func:`pipeline.evaluate.conformal_half_width`); a row's interval is the
final model's prediction p ± ``q s(p)`` (:func:`pipeline.evaluate.scale_fit`). The final check scores the share
of the test trial(s)' measured targets inside (``interval_coverage``).

Why the predicted value: a model's error grows with how hard the vehicle is driven (a thrust map's gain error, a
damping coefficient's error at speed), and one half-width calibrated on trials at full thrust is far too wide for
a trial driven gently. Chosen on validation seeds against one half-width and a spread in the model's inputs
(docs/models.md, "A band that grows with the prediction"); the one half-width is saved beside it
(``half_width_constant``).

Blocks of the training trials understate the error on the next trial: a block's neighbours in time are in its
fold's training rows, and the next trial may be driven otherwise. With two or more training trials the train stage
also fits each model without whole trials (:func:`held_out_trials`, at most ``coupled.folds`` fits, with the tune
stage's hyperparameters) and ``q`` is the wider of the blocked and the held-out trials' quantiles (chosen on
validation seeds; docs/models.md, "Calibrated on held-out trials").

Not normalized by each target's smoother SD (``udot_std_mps2`` ...; the decoupled study's choice): the coupled
models' residuals are mostly model error, which does not grow with the smoother's SD, and on the validation seeds
the normalized band missed more (docs/models.md, "Coupled models' intervals"). The normalized quantile is saved
beside it (``half_width_sd``) for comparison, where the store has the SDs.

Blocks are exchangeable only approximately (the targets' errors are correlated in time) and a test trial of
another regime is a covariate shift: docs/models.md, "Coupled models' intervals", says what guarantee remains and
measures it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from pipeline.evaluate import (
    INTERVAL_LEVEL,
    conformal_half_width,
    interval_half_width,
    scale_fit,
    sd_floor,
    trial_folds,
    trial_groups,
)
from pipeline.vocabulary import DOFS, accel_std_column, acceleration_column

log = logging.getLogger(__name__)

__all__ = ["METHOD", "METHOD_TRIALS", "target_sd_column", "target_sd", "held_out_trials", "oof_intervals",
           "interval_coverage"]

METHOD = "split conformal on the blocked CV's out-of-fold residuals, spread growing with |prediction|"
METHOD_TRIALS = ("split conformal: the wider of the blocked CV's and the held-out trials' quantiles of the "
                 "out-of-fold residuals, spread growing with |prediction|")


def target_sd_column(output: str) -> str | None:
    """The smoother's SD column of an acceleration output (``vdot_mps2`` -> ``vdot_std_mps2``); None for any
    other output."""
    return next((accel_std_column(d) for d in DOFS if acceleration_column(d) == output), None)


def target_sd(frame: pd.DataFrame, outputs: Sequence[str]) -> dict[str, np.ndarray | None]:
    """Per output the rows' target SDs (None where ``frame`` has no finite SD column for it: the interval is then
    one half-width); a non-finite or negative SD takes the median of the others, with a warning."""
    out: dict[str, np.ndarray | None] = {}
    for o in outputs:
        col = target_sd_column(o)
        sd = frame[col].to_numpy(dtype=float) if col is not None and col in frame.columns else None
        if sd is not None:
            bad = ~(np.isfinite(sd) & (sd >= 0))
            if bad.all():
                sd = None
            elif bad.any():
                log.warning("%s: %d of %d rows have no finite SD; they take the median SD", col, int(bad.sum()),
                            bad.size)
                sd = sd.copy()
                sd[bad] = float(np.median(sd[~bad]))
        out[o] = sd
    return out


def held_out_trials(trials: Sequence[Any], n_folds: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Folds of the train_test rows (``trials``: each row's trial) that each hold out whole training trials
    (:func:`pipeline.evaluate.trial_folds`, at most ``n_folds``): the interval's across-trial residuals. Empty
    with fewer than two trials of :data:`~pipeline.evaluate.MIN_TRIAL_ROWS` rows."""
    groups = trial_groups(trials, "auto")
    return [] if groups is None else trial_folds(groups, n_folds)


def oof_intervals(folds: Sequence[tuple[np.ndarray, np.ndarray]], y: np.ndarray, outputs: Sequence[str],
                  sd: Mapping[str, np.ndarray | None],
                  trial_pairs: Sequence[tuple[np.ndarray, np.ndarray]] = ()) -> dict[str, dict[str, Any]]:
    """Per output the :data:`~pipeline.evaluate.INTERVAL_LEVEL` interval from the blocked folds' ``(test rows,
    predictions (rows, outputs))`` of the targets ``y`` (train_test rows, outputs): ``scale: prediction``, a row's
    half-width ``half_width_scaled * (c_0 + c_1 |prediction|)`` (``spread`` = [c_0, c_1],
    :func:`~pipeline.evaluate.scale_fit`) and ``half_width`` its median over the calibration rows. With
    ``trial_pairs`` (the same pairs from models fitted without whole training trials, :func:`held_out_trials`) the
    quantile is the wider of the two sets'. Saved beside it, not used: ``half_width_constant``, the one half-width
    for every row (the wider of ``half_width_blocked`` and ``half_width_trials``), and with the rows' SDs
    (``sd[output]``) ``half_width_sd``, the quantile of ``|residual| / sd``, the wider of the two likewise
    (docs/models.md)."""
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    scored = {"blocked": _residuals(folds, y), **({"trials": _residuals(trial_pairs, y)} if len(trial_pairs) else {})}
    blocked = scored["blocked"]
    out: dict[str, dict[str, Any]] = {}
    for k, o in enumerate(outputs):
        q = {name: conformal_half_width(part.resid[:, k]) for name, part in scored.items()}
        spread, q_scaled = scale_fit([part.resid[:, k] for part in scored.values()],
                                     [np.column_stack([np.ones(len(part.pred)), np.abs(part.pred[:, k])])
                                      for part in scored.values()])
        typical = float(np.median(q_scaled * (spread[0] + spread[1] * np.abs(blocked.pred[:, k]))))
        entry: dict[str, Any] = {"level": INTERVAL_LEVEL, "rows": int(blocked.rows.size),
                                 "method": METHOD if len(scored) == 1 else METHOD_TRIALS, "scale": "prediction",
                                 "half_width": typical, "half_width_scaled": q_scaled, "spread": spread,
                                 "half_width_constant": max(q.values())}
        if len(scored) > 1:
            entry.update(half_width_blocked=q["blocked"], half_width_trials=q["trials"],
                         trials_held_out=len(trial_pairs))
        sd_o = sd.get(o)
        if sd_o is not None:  # the alternative, for comparison: each row's band q_sd times its target's SD
            entry.update(alternative_sd_column=target_sd_column(o),
                         half_width_sd=max(conformal_half_width(part.resid[:, k] / sd_floor(sd_o[part.rows]))
                                           for part in scored.values()))
        out[o] = entry
    return out


class _Scored(NamedTuple):
    rows: np.ndarray   # train_test rows
    pred: np.ndarray   # their out-of-fold predictions (rows, outputs)
    resid: np.ndarray  # |target - prediction|


def _residuals(pairs: Sequence[tuple[np.ndarray, np.ndarray]], y: np.ndarray) -> _Scored:
    """The rows of ``pairs`` (``(test rows, predictions (rows, outputs))``), their predictions and residuals."""
    rows = np.concatenate([np.asarray(r) for r, _ in pairs])
    pred = np.concatenate([np.asarray(p, dtype=float).reshape(len(r), y.shape[1]) for r, p in pairs])
    return _Scored(rows, pred, np.abs(y[rows] - pred))


def interval_coverage(intervals: Mapping[str, dict[str, Any]], y: np.ndarray, pred: np.ndarray,
                      outputs: Sequence[str], sd: Mapping[str, np.ndarray | None]) -> dict[str, float]:
    """Per output the share of the rows' measured targets ``y`` inside prediction ± the interval's half-width (each
    row's own: :func:`pipeline.evaluate.interval_half_width`)."""
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    pred = np.asarray(pred, dtype=float).reshape(len(pred), -1)
    return {o: float(np.mean(np.abs(y[:, k] - pred[:, k]) <= interval_half_width(intervals[o], sd.get(o),
                                                                                  pred[:, k])))
            for k, o in enumerate(outputs)}
