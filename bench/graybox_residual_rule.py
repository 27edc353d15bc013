"""The gray box's residual rule (keep the residual SVR on an output only where its CV says it helps) measured from
two runs of ``bench/coupled_study.py --json``: one with the residual always kept (a checkout before the rule, or
``coupled.residual_min_cv_r2: null``) and one with the rule (its JSON records each output's verdict with the CV R²
and SE that decided).

Per seed and output: the residual's CV R² ± SE, the old gray box, the gated one and its base McFarland-Whitcomb;
then, per rule, mean and worst over the seeds of the gray box that rule gives and its smallest margin over the base
(a dropped residual gives the base's cell exactly, a kept one the old gray box's: the hyperparameters are the same in
both runs, so other thresholds need no rerun).

    python bench/coupled_study.py --no-cv --duration 300 --max-samples 600 --seeds 40 41 --json /tmp/gate_val.json
    (the same with the rule off: /tmp/gate_val_base.json)
    python bench/graybox_residual_rule.py /tmp/gate_val_base /tmp/gate_val
"""

from __future__ import annotations

import json
import re
import sys

import numpy as np

OUTPUTS = ["udot_mps2", "vdot_mps2", "rdot_radps2"]
THRESHOLDS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)


def main(base_stem: str, gate_stem: str) -> None:
    for preset in ("gentle", "hard"):
        with open(f"{base_stem}_{preset}.json") as f:
            base = {r["seed"]: r for r in json.load(f)}
        with open(f"{gate_stem}_{preset}.json") as f:
            gate = {r["seed"]: r for r in json.load(f)}
        print(f"\n{preset} preset, seeds {sorted(gate)}")
        rows = {}
        for s in sorted(gate):
            for o in OUTPUTS:
                text = gate[s]["residual"]["graybox"][o]
                cv, se = map(float, re.search(r"CV R² (-?[\d.]+) ± ([\d.]+)", text).groups())
                old, new = base[s]["models"]["graybox"][o], gate[s]["models"]["graybox"][o]
                mw = gate[s]["models"]["mcfarland_whitcomb"][o]
                rows[(s, o)] = (cv, se, old, mw)
                print(f"seed {s} {o}: residual CV R² {cv:.3f} ± {se:.3f}; gray box old {old:.4f}, gated {new:.4f}; "
                      f"McFarland-Whitcomb {mw:.4f}")
        rules = {"always kept (old)": lambda cv, se: True, "CV R² > 0": lambda cv, se: cv > 0,
                 **{f"CV R² - SE > {t:g}": (lambda cv, se, t=t: cv - se > t) for t in (0.0, *THRESHOLDS)}}
        print("| rule | " + " | ".join(f"{o} mean" for o in OUTPUTS) + " | "
              + " | ".join(f"{o} worst" for o in OUTPUTS) + " | min (gray box - base) |")
        print("| --- |" + " ---: |" * 7)
        for name, keep in rules.items():
            cell = {k: (old if keep(cv, se) else mw) for k, (cv, se, old, mw) in rows.items()}
            mean = [np.mean([cell[(s, o)] for s in gate]) for o in OUTPUTS]
            worst = [min(cell[(s, o)] for s in gate) for o in OUTPUTS]
            gap = min(cell[k] - rows[k][3] for k in rows)
            print(f"| {name} | " + " | ".join(f"{v:.3f}" for v in mean + worst) + f" | {gap:+.3f} |")


if __name__ == "__main__":
    main(*sys.argv[1:3])
