"""Paper grid vs fast search on a reduced problem where the full grid is still affordable.

Reduced problem: WDSE-SVR with the 3 velocity inputs (u, v, r) -> rdot, so 3 gammas + C + epsilon = 5
hyperparameters x 5 candidates = 3,125 grid candidates x 3 blocked folds = 9,375 fits; the fast search is capped
at 1 % of that (31 candidates = 93 fits). Both are scored with the same blocked 3-fold CV on the same rows.

Usage: python bench/search.py [n_samples] [n_jobs]
"""

from __future__ import annotations

import sys

from pipeline.coupled import synthetic_frame
from pipeline.models.search import fast_search, grid_search


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 240
    n_jobs = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    frame = synthetic_frame(n, seed=3, split="tuning")
    X, y = frame[["u_mps", "v_mps", "r_radps"]].to_numpy(), frame["rdot_radps2"].to_numpy()
    grid = grid_search("wdse_svr", X, y, n_folds=3, n_jobs=n_jobs)
    budget = max(1, grid.n_candidates // 100)
    fast = fast_search("wdse_svr", X, y, n_folds=3, max_evals=budget)
    print(f"reduced problem: WDSE-SVR, inputs u v r -> rdot, n = {n}, blocked 3-fold CV on the tuning rows")
    print("| search | candidates | SVR fits | fits / grid fits | best CV R² | wall s |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for r in (grid, fast):
        print(f"| {r.method} | {r.n_candidates} | {r.n_fits} | {r.n_fits / grid.n_fits:.2%} | {r.best_score:.4f} | "
              f"{r.elapsed_s:.1f} |")
    print(f"fast - grid best CV R²: {fast.best_score - grid.best_score:+.4f} (GP seed fit {fast.gp_fit_s:.1f} s, "
          "not counted as SVR fits)")


if __name__ == "__main__":
    main()
