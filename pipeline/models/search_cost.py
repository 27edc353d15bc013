"""What a search's candidates cost, and the iteration cap that keeps each one's cost near the others'.

libsvm's iterations are a fit's cost: on one search's folds (the same rows for every candidate, the kernel matrix
cached) a fit's CPU grows with them, and a candidate with a large C and a tiny epsilon can need a hundred times
the iterations of its neighbours. Two caps stop a fit (:class:`IterationCap`); a stopped fit is scored as it is
(docs/models.md, "Each candidate's cost is capped and reported"):

* the absolute cap, ``iter_per_row`` x the folds' mean training rows, against runaway fits;
* the relative cap, once the search has scored a few candidates: ``ratio`` x the median iterations of its fits
  so far, but never below twice the iterations of the best candidate so far (the region the search is closing
  in on may need many: the demo's best r_dot candidates need several times the median) nor below
  ``floor_per_row`` x the rows. It is what keeps a search's slowest candidate within a bounded multiple of
  its median one: the candidates it stops are the costly ones far from the best.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from pipeline.errors import ModelError

log = logging.getLogger(__name__)

__all__ = ["ITER_CAP_RATIO", "ITER_FLOOR_PER_ROW", "ITER_PER_ROW", "ITER_WARMUP_CANDIDATES", "IterationCap",
           "candidate_entry", "cost_summary", "iteration_cap", "log_capped"]

#: libsvm's iterations per candidate fit of a search, per training row of the fold (docs/models.md): above the
#: slowest candidate of the demo's searches, so only a runaway fit is stopped by it
ITER_PER_ROW: float | None = 1000.0
#: the relative cap: a fit stops at this many times the median iterations of its search's fits so far ...
ITER_CAP_RATIO: float | None = 20.0
#: ... once this many candidates are scored, and never below this many iterations per training row
ITER_WARMUP_CANDIDATES = 5
ITER_FLOOR_PER_ROW: float = 100.0
SLOW_FIELDS = ("params", "score", "cpu_s", "n_iter", "capped")  # a slowest candidate's fields in the trace


def iteration_cap(iter_per_row: float | None, folds: list[tuple[np.ndarray, np.ndarray]]) -> int | None:
    """libsvm's iterations per candidate fit: ``iter_per_row`` x the folds' mean training rows (None: no cap)."""
    if iter_per_row is not None and iter_per_row <= 0:
        raise ModelError(f"iter_per_row must be > 0 or None, got {iter_per_row}")
    rows = float(np.mean([len(tr) for tr, _ in folds]))
    return None if iter_per_row is None else max(1, int(round(iter_per_row * rows)))


class IterationCap:
    """The iteration cap of a search's next fit: the absolute cap ``static`` (None: none), and once ``warmup``
    fits are recorded, at most ``ratio`` x the median of the recorded fits' iterations, but at least twice the
    largest fold iterations of the best-scoring candidate recorded and at least ``floor`` (``ratio`` None: the
    absolute cap only). :meth:`record` each candidate's fits as they are scored; the cap depends only on what was
    scored before, so a serial search stays deterministic."""

    def __init__(self, static: int | None, ratio: float | None = ITER_CAP_RATIO, floor: int = 1,
                 warmup: int = 1) -> None:
        if ratio is not None and not (ratio >= 1.0 and math.isfinite(ratio)):
            raise ModelError(f"the iteration cap's ratio must be a number >= 1 or None, got {ratio}")
        self.static, self.ratio, self.floor, self.warmup = static, ratio, max(1, int(floor)), max(1, warmup)
        self.iters: list[int] = []
        self.best: tuple[float, int] | None = None  # the best candidate's score and its fits' largest iterations

    def __call__(self) -> int | None:
        if self.ratio is None or len(self.iters) < self.warmup:
            return self.static
        relative = max(self.floor, int(math.ceil(self.ratio * float(np.median(self.iters)))),
                       2 * (self.best[1] if self.best else 0))
        return relative if self.static is None else min(self.static, relative)

    def record(self, fits: list[tuple[float, float, int]]) -> None:
        """A candidate's fits (R², CPU seconds, iterations), in the order the search scored them."""
        self.iters.extend(n for _, _, n in fits)
        score = float(np.mean([r2 for r2, _, _ in fits]))
        if self.best is None or score > self.best[0]:
            self.best = (score, max(n for _, _, n in fits))

    def settings(self) -> dict[str, Any]:
        return {"max_iter": self.static, "iter_cap_ratio": self.ratio, "iter_floor": self.floor}


def candidate_entry(params: dict[str, Any], fits: list[tuple[float, float, int]], max_iter: int | None,
                    **extra: Any) -> dict[str, Any]:
    """A candidate's trace entry: mean fold R² (``score``), its standard error, the CPU seconds of its fits, the
    cap its fits ran under (``max_iter``) and how many of them it stopped (``capped``)."""
    scores = [r2 for r2, _, _ in fits]
    se = float(np.std(scores, ddof=1) / math.sqrt(len(scores))) if len(scores) > 1 else 0.0
    return {"params": params, "score": float(np.mean(scores)), "se": se, **extra,
            "cpu_s": round(float(sum(c for _, c, _ in fits)), 6), "n_fits": len(fits),
            "n_iter": max(n for _, _, n in fits), "max_iter": max_iter,
            "capped": sum(max_iter is not None and n >= max_iter for _, _, n in fits)}


def cost_summary(trace: list[dict[str, Any]], cap: int | None | IterationCap, n_slowest: int = 3) -> dict[str, Any]:
    """A search's cost from its trace: the CPU of its candidates' fits (total, median and largest per
    candidate; each measured in the process that ran it, so a parallel search counts its workers'), its
    slowest fit over its median fit (``slowest_fit_over_median``, per fit: candidates may fit different numbers
    of folds), the caps, how many candidates they stopped, and the ``n_slowest`` candidates."""
    cpu = [t["cpu_s"] for t in trace]
    per_fit = [t["cpu_s"] / t["n_fits"] for t in trace if t.get("n_fits")]
    median_fit = float(np.median(per_fit)) if per_fit else 0.0
    slowest = sorted(range(len(trace)), key=lambda k: -trace[k]["cpu_s"])[:n_slowest]
    caps = cap.settings() if isinstance(cap, IterationCap) else {"max_iter": cap}
    return {"fits_cpu_s": round(float(sum(cpu)), 4),
            "median_candidate_cpu_s": round(float(np.median(cpu)), 6) if cpu else 0.0,
            "max_candidate_cpu_s": round(float(max(cpu, default=0.0)), 6),
            "slowest_fit_over_median": round(max(per_fit) / median_fit, 2) if median_fit > 0 else None, **caps,
            "n_capped": sum(1 for t in trace if t["capped"]),
            "slowest_by_cpu": [{"candidate": k, **{f: trace[k][f] for f in SLOW_FIELDS}} for k in slowest]}


def log_capped(model: str, n_candidates: int, cost: dict[str, Any]) -> None:
    if cost.get("n_capped"):
        log.info("%s search: %d of %d candidates stopped by libsvm's iteration cap (scored as they are); slowest "
                 "%.3g CPU-s, median %.3g", model, cost["n_capped"], n_candidates, cost["max_candidate_cpu_s"],
                 cost["median_candidate_cpu_s"])
