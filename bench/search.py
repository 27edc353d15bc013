"""Paper grid vs the default (fast) search on simulated trial data where the full grid is still affordable.

Problem: WDSE-SVR, vdot from [v, r, n3] (sway and yaw rate and the lateral thruster's speed), ``n`` rows
(default 240, 0.5 s apart) of a trial of the project's simulator (``pipeline.sim``, DAGON with coupled true
damping), measurement noise of 2 % of each signal's SD. 3 gammas + C + epsilon = 5 hyperparameters x 5
candidates (the paper's Table II protocol) = 3,125 candidates x 3 blocked folds = 9,375 SVR fits. The fast search
is capped at 1 % of the grid's fits. Both score candidates by the same blocked 3-fold CV mean R² on the same rows.

Usage: python bench/search.py [n_samples] [n_jobs] [seed ...]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from pipeline.models.search import fast_search, grid_search
from pipeline.sim import load_example_vehicle, simulate_trial

INPUTS = ["v_mps", "r_radps", "n3_rpm"]
OUTPUT = "vdot_mps2"


def problem(n: int, seed: int = 7, noise: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rows 0.5 s apart of one simulated trial, with measurement noise."""
    truth = simulate_trial(load_example_vehicle(), duration_s=0.5 * n + 1.0, seed=seed).truth
    rows = truth.iloc[np.arange(n) * 100]  # 200 Hz truth -> 2 Hz
    rng = np.random.default_rng(seed)
    X = rows[INPUTS].to_numpy(float)
    y = rows[OUTPUT].to_numpy(float)
    X = X + noise * X.std(axis=0) * rng.normal(size=X.shape)
    y = y + noise * y.std() * rng.normal(size=y.shape)
    return X, y


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 240
    n_jobs = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    seeds = [int(s) for s in sys.argv[3:]] or [0]
    X, y = problem(n)
    t0 = time.perf_counter()
    grid = grid_search("wdse_svr", X, y, n_folds=3, n_jobs=n_jobs)
    rows = [("paper grid (5 per hyperparameter)", grid)]
    budget = max(1, grid.n_fits // 100)
    for seed in seeds:
        fast = fast_search("wdse_svr", X, y, n_folds=3, max_fits=budget, seed=seed)
        rows.append((f"fast (default), seed {seed}", fast))
    print(f"WDSE-SVR, {OUTPUT} from {' '.join(INPUTS)}: n = {n} rows of a simulated DAGON trial (pipeline.sim), "
          f"blocked 3-fold CV; 5 candidates x {len(grid.best_params['gammas']) + 2} hyperparameters; "
          f"fast budget {budget} fits (1 % of the grid's); {n_jobs} jobs; total {time.perf_counter() - t0:.0f} s")
    print("| method | SVR fits | % of grid fits | best CV R² | wall s |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name, r in rows:
        share = 100 * r.n_fits / grid.n_fits
        print(f"| {name} | {r.n_fits} | {share:.2f} % | {r.best_score:.4f} | {r.elapsed_s:.1f} |")
    for name, r in rows[1:]:
        print(f"{name}: best - grid best = {r.best_score - grid.best_score:+.4f} (GP seed fit {r.gp_fit_s:.2f} s)")


if __name__ == "__main__":
    main()
