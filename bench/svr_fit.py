"""Fit time of WDSE-SVR vs plain RBF-SVR at n = 10k (same libsvm RBF underneath; the ratio should be ~1).

Usage: python bench/svr_fit.py [n_samples] [repeats]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from pipeline.models.svr import RBFSVR, WDSESVR
from pipeline.studies.coupled import synthetic_frame

INPUTS = ["u_mps", "v_mps", "r_radps", "n1_rpm", "n2_rpm", "n3_rpm"]


def best_time(est, X, y, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        est.fit(X, y)
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10_000
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    frame = synthetic_frame(n, seed=0)
    X, y = frame[INPUTS].to_numpy(), frame["rdot_radps2"].to_numpy()
    eps = 0.01 * float(np.std(y))
    g = 1.0 / X.shape[1]
    rows = [("RBF-SVR (gamma=1/6)", RBFSVR(gamma=g, C=1.0, epsilon=eps)),
            ("WDSE-SVR (gammas=1/6)", WDSESVR(gammas=[g] * 6, C=1.0, epsilon=eps)),
            ("WDSE-SVR (gammas varied)", WDSESVR(gammas=[0.05, 0.2, 0.1, 0.3, 0.1, 0.05], C=1.0, epsilon=eps))]
    base = None
    print(f"n = {n}, best of {repeats} fits, single thread libsvm")
    print(f"| {'model':<26} | fit s | ratio to RBF | support vectors |")
    print(f"| {'-' * 26} | ---: | ---: | ---: |")
    for name, est in rows:
        t = best_time(est, X, y, repeats)
        base = base or t
        print(f"| {name:<26} | {t:.2f} | {t / base:.2f} | {est.n_support_} |")


if __name__ == "__main__":
    main()
