"""The gray box's second verdict, drawn from the train stage's CV: per output, its residual stays only where the
gray box beat its own base on the CV's folds (:func:`pipeline.models.graybox.paired_verdict`).

The tune stage's verdict judges the residual search's CV on the residual target; this one judges what a user gets,
the whole gray box against the base it is built on, fold by fold on the same rows. Where it drops an output, that
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

__all__ = ["narrow_to_verdict"]


def narrow_to_verdict(specs: Sequence[dict[str, Any]], results: Sequence[dict[str, Any]], outputs: Sequence[str]
                      ) -> dict[str, str]:
    """Apply the paired verdict to one gray box's train tasks (``specs`` and their ``results`` in order, the final
    fit last; each result with its base's predictions, ``base``), in place. Returns per output the verdict's words;
    {} where fewer than two folds ran (no verdict: the tune stage's stands)."""
    folds = [r for s, r in zip(specs, results, strict=True) if s["kind"] == "fold"]
    final = results[-1]
    if len(folds) < 2:
        return {}
    verdicts, base_only = {}, []
    for k, out in enumerate(outputs):
        keep, verdicts[out] = paired_verdict([f["fold"]["test"][out]["r2"] - f["base"]["scores"]["test"][out]["r2"]
                                              for f in folds])
        if not (keep and k in final["estimator"].kept_outputs_):
            base_only.append(k)
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
    return verdicts
