"""How GP fitting time grows with the number of training samples, and what subsampling costs in accuracy.

scikit-learn's GaussianProcessRegressor is O(n^3) per marginal-likelihood evaluation, so the decoupled study
subsamples evenly in velocity (``DampingGP(max_samples=...)``, param ``decoupled.gp_max_samples``). This bench
fits :class:`pipeline.models.decoupled.DampingGP` on synthetic damping data (known truth, noise 2 N) with
increasing ``max_samples`` and prints fit time, predict time and the error of the learned curve against the truth.

    python -m bench.gp [--sizes 250 500 1000 2000] [--n 12000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pipeline.models.decoupled import DampingGP


def truth(v: np.ndarray) -> np.ndarray:
    return 20.0 * v + 60.0 * v * np.abs(v) + 80.0 * v**3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[250, 500, 1000, 2000])
    parser.add_argument("--n", type=int, default=12000, help="samples in the full data set (10 min at 20 Hz)")
    parser.add_argument("--noise", type=float, default=2.0)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    t = np.arange(args.n) / 20.0
    v = 0.8 * np.sin(2 * np.pi * t / 40.0) * np.sin(2 * np.pi * t / 170.0) + 0.02 * rng.standard_normal(args.n)
    y = truth(v) + args.noise * rng.standard_normal(args.n)
    grid = np.linspace(v.min(), v.max(), 400)[:, None]
    print(f"full data: n={args.n}, noise std={args.noise} N")
    print(f"{'max_samples':>11} {'n_train':>7} {'fit_s':>8} {'predict_s':>9} {'MAE_truth_N':>11} "
          f"{'noise_learned':>13} {'cover_2sigma':>12}")
    for size in args.sizes:
        gp = DampingGP(max_samples=size)
        t0 = time.perf_counter()
        gp.fit(v[:, None], y)
        fit_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        mean, std = gp.predict(grid, return_std=True)
        pred_s = time.perf_counter() - t0
        err = np.abs(mean - truth(grid[:, 0]))
        cover = float(np.mean(err <= 2 * std))
        print(f"{size:>11} {gp.n_train_:>7} {fit_s:>8.2f} {pred_s:>9.3f} {err.mean():>11.3f} "
              f"{gp.noise_std_:>13.3f} {cover:>12.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
