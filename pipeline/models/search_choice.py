"""How a search picks from its trace: the smoothest kernel among near-ties, and why a warm start was kept."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["gammas", "kept_note", "smoothest_within"]


def kept_note(trace: list[dict[str, Any]], warm_score: float, n_folds: int) -> str:
    """Why the warm start survived: how many candidates of each phase were tried and how close they came."""
    others = [t for t in trace if t.get("phase") != "warm_start"]
    counts: dict[str, int] = {}
    for t in others:
        counts[t["phase"]] = counts.get(t["phase"], 0) + 1
    tried = ", ".join(f"{n} {ph}" for ph, n in counts.items()) or "none"
    if not others:
        return f"no candidate besides the warm start fitted in the budget (R2 {warm_score:.4f})"
    runner_up = max(t["score"] for t in others)
    spread = warm_score - min(t["score"] for t in others)
    why = ("the score is flat around it" if spread < 1e-3 else
           "every other candidate scored lower: a local optimum the budget did not escape")
    return (f"none of {len(others)} other candidates ({tried}; {n_folds}-fold CV) beat its tuning R2 "
            f"{warm_score:.4f} (runner-up {runner_up:.4f}, worst {warm_score - spread:.4f}): {why}")


def gammas(params: dict[str, Any]) -> list[float]:
    if "gammas" in params:
        return list(params["gammas"])
    return [v for k, v in params.items() if k.startswith("gamma")]


def smoothest_within(trace: list[dict[str, Any]], best: float, tolerance: float) -> tuple[dict[str, Any], float]:
    """Regularized choice: of the candidates scoring within ``tolerance`` (R²) of the best, the smoothest kernel
    (smallest sum of log gammas, then smallest C). The tuning block is short, so its CV score is a noisy estimate;
    among near-ties the wider kernel extrapolates better to the rest of the data."""
    near = [t for t in trace if t["score"] >= best - tolerance]
    pick = min(near, key=lambda t: (float(np.sum(np.log(gammas(t["params"])))), t["params"]["C"]))
    return pick["params"], float(pick["score"])
