"""The gray box against its own base in the train stage, per output, on its CV folds and on its held-out training
trials: recorded always, and with ``coupled.residual_fold_check`` a second verdict, the residual kept only where
the gray box beat its base there (:func:`pipeline.models.graybox.paired_verdict`).

The tune stage's verdict judges the residual search's CV on the residual target; this one judges what a user gets,
the whole gray box against the base it is built on, on the same rows: each held-out training trial (the fits
without a trial keep the final model's residuals) and each CV fold. Where it drops an output, that
output becomes the base's alone everywhere the train stage reports it: the folds' scores, the out-of-fold and
held-out-trial predictions the interval is calibrated on, the final check and the saved model
(:meth:`pipeline.models.graybox.GrayBox.narrowed`). So the CV, the interval and the file describe the model that is
offered. An output the final fit already gives to its base (the tune stage dropped its residual) is the base's in
the folds too.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pipeline.evaluate import regression_scores
from pipeline.models.graybox import paired_verdict

__all__ = ["fold_check"]


def fold_check(specs: Sequence[dict[str, Any]], results: Sequence[dict[str, Any]], outputs: Sequence[str], *,
               rule: str) -> dict[str, dict[str, Any]]:
    """The gray box against its base, per output: ``{"verdict": words, "differences": the CV folds' test R²
    differences, "trial_differences": the same on each held-out training trial (where there are two or more)}``,
    from one gray box's train tasks (``specs`` and their ``results`` in order, the final fit last; each result with
    its base's predictions, ``base``). ``rule`` (``coupled.residual_fold_check``): ``trials``, the residual stays
    only where the held-out trials say it helps (:func:`paired_verdict`; with fewer than two held out, nowhere:
    nothing then shows that a residual carries to another trial, and a CV within one trial does not predict it);
    ``folds``, where the CV folds do; ``off``, the comparison only recorded. A rule's verdict is applied to the
    results in place. {} where fewer than two folds ran and the rule drops nothing for want of trials."""
    folds = [r for s, r in zip(specs, results, strict=True) if s["kind"] == "fold"]
    final = results[-1]
    across = _held_out_trials(specs, results, outputs)
    no_trials = rule == "trials" and not across
    if len(folds) < 2 and not no_trials:
        return {}
    record, base_only = {}, []
    for k, out in enumerate(outputs):
        entry = {"differences": [f["fold"]["test"][out]["r2"] - f["base"]["scores"]["test"][out]["r2"] for f in folds],
                 **across.get(out, {})}
        scores = {key: paired_verdict(entry[key], over) for key, over in (("differences", "folds"),
                                                                          ("trial_differences", "held-out trials"))
                  if len(entry.get(key, ())) >= 2 and np.all(np.isfinite(entry[key]))}
        words = "; ".join(score for _, score in scores.values()) or "no finite scores to compare"
        if no_trials:
            record[out] = {"verdict": f"dropped (fewer than two training trials held out: nothing shows the residual "
                                      f"carries to another trial; {words})", **entry}
            base_only.append(k)
            continue
        judged = scores.get({"folds": "differences", "trials": "trial_differences"}.get(rule, ""))
        if judged is None:
            record[out] = {"verdict": words, **entry}
            continue
        record[out] = {"verdict": f"kept ({words})" if judged[0] else f"dropped ({words}: not above 0 by 1 SE)",
                       **entry}
        if not (judged[0] and k in final["estimator"].kept_outputs_):
            base_only.append(k)
    if not base_only:
        return record
    for spec, res in zip(specs, results, strict=True):
        if spec["kind"] == "fold":
            for k in base_only:
                for split in ("train", "test"):
                    res["fold"][split][outputs[k]] = res["base"]["scores"][split][outputs[k]]
        if res.get("pred") is not None:
            res["pred"] = np.array(res["pred"], dtype=float)
            res["pred"][:, base_only] = res["base"]["pred"][:, base_only]
    final["estimator"] = final["estimator"].narrowed([k for k in range(len(outputs)) if k not in base_only])
    if final["final"] is not None:
        final["final"] = regression_scores(np.asarray(specs[-1]["y_test"], dtype=float), final["pred"], outputs)
    return record


def _held_out_trials(specs: Sequence[dict[str, Any]], results: Sequence[dict[str, Any]], outputs: Sequence[str]
                     ) -> dict[str, dict[str, list[float]]]:
    """Per output, ``trial_differences``: the gray box's test R² minus its base's on each held-out training trial
    (the train stage's fits without whole trials, whose gray boxes keep the final model's residuals, fitted with
    the tune stage's hyperparameters); {} with fewer than two training trials."""
    pairs = [(s, r) for s, r in zip(specs, results, strict=True) if s["kind"] == "trial" and "base" in r]
    if not pairs:
        return {}
    y = np.asarray(specs[0]["y"], dtype=float)
    scores = [(regression_scores(y[s["test"]], r["pred"], outputs),
               regression_scores(y[s["test"]], r["base"]["pred"], outputs)) for s, r in pairs]
    return {out: {"trial_differences": [gray[out]["r2"] - base[out]["r2"] for gray, base in scores]}
            for out in outputs}
