"""How often the physics models' 90 % coefficient intervals (``fit_intervals``, the block bootstrap of
``pipeline.models.bootstrap``) cover the true coefficients.

Per seed, a plant exactly in the model's family (the tests' plants: ``tests/models/fossen_data.py`` for Fossen, a
surge both ways; ``tests/models/test_explicit_eiv.py`` for Gertler-Hagen and McFarland-Whitcomb), its exact
velocities and thrust, and accelerations with AR(1) errors of 30 % of their SD and lag-1 correlation ``--rho``
(smoothed targets are correlated over seconds); the model fitted by WTLS (Fossen: the true terms, no selection, so
the intervals are tested, not the selection), then the intervals. Printed: the share of
(seed, main coefficient) pairs inside, per coefficient, and the block length. ``--naive``: blocks of one row (the
ordinary bootstrap), for comparison.

    python bench/coefficient_intervals.py --seeds 6 29 --rho 0.95        # validation (chose the block factor)
    python bench/coefficient_intervals.py --seeds 100 111 --rho 0.9 --rows 3000   # the test's seeds
    python bench/coefficient_intervals.py --model mcfarland_whitcomb --seeds 100 107 --rows 2000
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.models import bootstrap  # noqa: E402
from pipeline.models.explicit import GertlerHagen, McFarlandWhitcomb  # noqa: E402
from pipeline.models.fossen import Fossen3DOF  # noqa: E402
from tests.models import test_explicit_eiv as explicit_plant  # noqa: E402
from tests.models.fossen_data import DT_S, M_RB, TRUTH, run  # noqa: E402

FOSSEN_MAIN = ("X_udot", "Y_vdot", "Y_rdot", "N_rdot", "X_u", "X_|u|u", "Y_v", "Y_|v|v", "N_r", "N_|r|r")
EXPLICIT = {"gertler_hagen": GertlerHagen, "mcfarland_whitcomb": McFarlandWhitcomb}


def fitted(model: str, seed: int, rows: int, rho: float):
    """(the fitted model, X, y with the errors, the truth by coefficient, the main coefficients)."""
    if model == "fossen":
        _, _, _, X, y = run(seed, n=rows)
    else:
        _, _, _, X, y = explicit_plant.dataset(EXPLICIT[model], seed, n=rows)
    sd = 0.3 * y.std(axis=0)
    e = lfilter([np.sqrt(1 - rho**2)], [1.0, -rho], np.random.default_rng(1000 + seed).normal(size=y.shape), axis=0)
    yn = y + e * sd
    noise = (0, 0, 0, 0, 0, 0, *sd)
    if model == "fossen":
        est = Fossen3DOF(rigid_body_mass=M_RB, noise_std=noise, dt_s=DT_S, select=False,
                         terms=[t for t in TRUTH if not t.endswith("dot")]).fit(X, yn)
        return est, X, yn, TRUTH, FOSSEN_MAIN
    est = EXPLICIT[model](noise_std=noise).fit(X, yn)
    truth = dict(zip(est.param_names, explicit_plant.true_theta(est), strict=True))
    return est, X, yn, truth, explicit_plant.MAIN[EXPLICIT[model]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", choices=["fossen", *EXPLICIT], default="fossen")
    ap.add_argument("--seeds", type=int, nargs=2, default=[100, 111], metavar=("FIRST", "LAST"))
    ap.add_argument("--rho", type=float, default=0.9)
    ap.add_argument("--rows", type=int, default=6000)
    ap.add_argument("--naive", action="store_true", help="blocks of one row (the ordinary bootstrap)")
    args = ap.parse_args()
    if args.naive:
        bootstrap.block_rows = lambda residuals, runs: 1
    inside: dict[str, list[bool]] = {}
    lengths, cpu = [], []
    for seed in range(args.seeds[0], args.seeds[1] + 1):
        model, X, y, truth, main_terms = fitted(args.model, seed, args.rows, args.rho)
        t0 = time.process_time()
        ci = model.fit_intervals(X, y).coefficient_intervals_
        cpu.append(time.process_time() - t0)
        lengths.append(ci["block_rows"])
        for k in main_terms:
            lo, hi = ci["intervals"][k]
            inside.setdefault(k, []).append(lo <= truth[k] <= hi)
    share = np.mean([v for k in inside for v in inside[k]])
    print(f"{args.model}, seeds {args.seeds[0]}-{args.seeds[1]}, rho {args.rho}, {args.rows} rows: 90 % intervals "
          f"cover {share:.3f} of {sum(len(v) for v in inside.values())} (seed, coefficient) pairs; block rows "
          f"{min(lengths)}-{max(lengths)}; CPU per fit_intervals median {np.median(cpu):.2f} s")
    print("| coefficient | inside |\n| --- | ---: |")
    for k, v in inside.items():
        print(f"| {k} | {np.mean(v):.2f} |")


if __name__ == "__main__":
    main()
