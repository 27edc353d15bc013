"""The manoeuvring family (``abkowitz``, pipeline/models/manoeuvring.py) on the simulated ship of
``pipeline.sim.synthetic.SHIP_TRUTH``, whose true forces are in the family.

Per seed set S: fitting runs seeds 3S, 3S+1, 3S+2 (300 s at 20 Hz each, zig-zags and rudder steps, 10 % noise on
the accelerations); the unseen zig-zag seed 100 + 3S (amplitudes 15 / 25 deg, thrusts 15-30 N). Prints each
coefficient's worst and mean relative error, the terms kept that are not in the truth, the true terms dropped, and
the unseen zig-zag's R² per DOF (against its noisy targets). ``--study``: the coupled study (tune, 2-fold CV, final
check) on 10-Hz runs, the abkowitz model against its gray box and the nu/tau families.

    python bench/ship_manoeuvring.py 0 1 2 3 4 5 6 7 8 9
    python bench/ship_manoeuvring.py --study 0 1
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pandas as pd

from pipeline.config.params import CoupledParams
from pipeline.models.manoeuvring import Abkowitz3DOF
from pipeline.sim.synthetic import SHIP_TRUTH, ship_zigzag
from pipeline.studies.coupled import run_study

INPUTS = ["u_mps", "v_mps", "r_radps", "T_prop_N", "rudder_rad"]
OUTPUTS = ["udot_mps2", "vdot_mps2", "rdot_radps2"]


def _unseen(s: int, rate_hz: float = 20.0, split: str = "test") -> pd.DataFrame:
    return ship_zigzag(300.0, rate_hz=rate_hz, seed=100 + 3 * s, amplitudes_deg=(15.0, 25.0), thrusts_N=(15.0, 30.0),
                       trial=f"unseen{s}", split=split)


def recovery(s: int) -> None:
    train = pd.concat([ship_zigzag(300.0, seed=3 * s + k, trial=f"ship{k}", manoeuvres=("zigzag", "steps"))
                       for k in range(3)], ignore_index=True)
    t0 = time.perf_counter()
    model = Abkowitz3DOF().fit(train[INPUTS].to_numpy(), train[OUTPUTS].to_numpy())
    cost = time.perf_counter() - t0
    coef = model.coefficients()
    err = {k: abs(coef[k] - v) / abs(v) for k, v in SHIP_TRUTH.items()}
    worst = max(err, key=err.get)
    extra = [k for k in model.selected_terms_ if k not in SHIP_TRUTH]
    missed = [k for k in SHIP_TRUTH if k not in model.selected_terms_]
    test = _unseen(s)
    y, p = test[OUTPUTS].to_numpy(), model.predict(test[INPUTS].to_numpy())
    r2 = 1 - ((y - p) ** 2).sum(0) / ((y - y.mean(0)) ** 2).sum(0)
    print(f"set {s}: worst {worst} {100 * err[worst]:.1f} %, mean {100 * np.mean(list(err.values())):.1f} %, "
          f"extra {extra}, missed {missed}, unseen R2 {np.round(r2, 4).tolist()}, fit {cost:.2f} s", flush=True)


def study(s: int) -> None:
    runs = [ship_zigzag(300.0, rate_hz=10.0, seed=3 * s + k, trial=f"ship{k}", manoeuvres=("zigzag", "steps"),
                        split="tuning" if k == 0 else "train_test") for k in range(3)]
    frame = pd.concat([*runs, _unseen(s, 10.0)], ignore_index=True)
    params = CoupledParams(inputs=INPUTS, models=["abkowitz", "graybox_abkowitz", "fossen", "gertler_hagen",
                                                  "mcfarland_whitcomb"], tuning="split", folds=2, n_jobs=1)
    out = run_study(frame, params)
    for m in params.models:
        if m in out["failed"]:
            print(f"set {s} {m}: failed {out['failed'][m]}")
            continue
        final = out["results"][m]["final"]
        print(f"set {s} {m}: unseen R2 {[round(final[o]['r2'], 4) for o in OUTPUTS]}", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    run = study if args and args[0] == "--study" else recovery
    for seed_set in [int(a) for a in args if a != "--study"] or [0]:
        run(seed_set)
