"""How close Fossen's 3-DOF model (``pipeline.models.fossen``, the coupled study's defaults: WTLS, term selection by
free runs, dissipative damping) comes to the true coefficients when the truth is in its family.

Per seed, the tests' plant (``tests/models/fossen_data.py``: added mass, linear + |nu|nu damping with sway-yaw
cross terms, a surge both ways) at 20 Hz for ``--seconds``, with realistic errors: 0.015 m/s on u and v, 0.005 rad/s
on r, and 30 % of each acceleration's SD on nudot, white; the noise SDs given, as the study gives the smoother's.
Printed per main coefficient (the four added masses and each DOF's linear and quadratic damping in its own velocity):
the mean relative error over the seeds (the bias), the worst, the share of seeds within 10 %, and the median
half-width of its 90 % interval (``fit_intervals``) relative to the truth, which says how well one trial of that
length determines it.

    python bench/fossen_recovery.py --seeds 300 319 --seconds 300 480 600
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.models.fossen import Fossen3DOF  # noqa: E402
from tests.models.fossen_data import DT_S, M_RB, TRUTH, run  # noqa: E402

MAIN = ("X_udot", "Y_vdot", "Y_rdot", "N_rdot", "X_u", "X_|u|u", "Y_v", "Y_|v|v", "N_r", "N_|r|r")


def errors(seed: int, rows: int) -> tuple[dict[str, float], dict[str, float]]:
    """(relative error, relative 90 % half-width) per main coefficient; a term the selection dropped: error -1."""
    X, y, noise, _, _ = run(seed, n=rows, rel_acc=0.3, nu_noise=True)
    model = Fossen3DOF(rigid_body_mass=M_RB, noise_std=noise, dt_s=DT_S).fit(X, y)
    coef = model.coefficients()
    ci = model.fit_intervals(X, y).coefficient_intervals_["intervals"]
    err = {k: coef.get(k, 0.0) / TRUTH[k] - 1 for k in MAIN}
    half = {k: (ci[k][1] - ci[k][0]) / 2 / abs(TRUTH[k]) if k in ci else np.nan for k in MAIN}
    return err, half


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs=2, default=[300, 319], metavar=("FIRST", "LAST"))
    ap.add_argument("--seconds", type=float, nargs="+", default=[300.0, 480.0])
    args = ap.parse_args()
    seeds = range(args.seeds[0], args.seeds[1] + 1)
    for seconds in args.seconds:
        rows = int(round(seconds / DT_S))
        runs = [errors(s, rows) for s in seeds]
        err = np.array([[e[k] for k in MAIN] for e, _ in runs])
        half = np.array([[h[k] for k in MAIN] for _, h in runs])
        worst = np.abs(err).max(axis=1)
        print(f"\n{seconds:g} s ({rows} rows), seeds {args.seeds[0]}-{args.seeds[1]}: every main coefficient within "
              f"10 % on {np.mean(worst < 0.1):.2f} of the seeds; the worst error {worst.max():.3f} (seed "
              f"{seeds[int(worst.argmax())]})")
        print("| coefficient | mean error | worst error | within 10 % | 90 % half-width (median) |")
        print("| --- | ---: | ---: | ---: | ---: |")
        for j, k in enumerate(MAIN):
            w = int(np.abs(err[:, j]).argmax())
            print(f"| {k} | {err[:, j].mean():+.3f} | {err[w, j]:+.3f} | {np.mean(np.abs(err[:, j]) < 0.1):.2f} | "
                  f"{np.nanmedian(half[:, j]):.3f} |")


if __name__ == "__main__":
    main()
