"""How much of each family regime's acceleration the vehicle's own model explains (a physics check, no model fitted).

Per regime kind (sines, thrust level, tether, Hall speeds) the first simulator seed in ``--seeds`` that draws it
(``pipeline.sim.regime``): one trial, and the R² of the TRUE model without the unknown force, at the TRUE inputs
(velocities, attitude, thruster speeds), against the true accelerations (u̇, v̇, ṙ). 1 where nothing unknown acts;
below, the share the tether leaves unexplained: the ceiling of ``bench/coupled_study.py`` cannot exceed it.
The family's tether is scaled to the thrust (``Regime.disturbance_model``); ``--hard-tether``: the hard preset's
tether unscaled at every thrust, as the family first drew it.

    python bench/regime_share.py                        # seeds 6400-6599: the family's validation range
    python bench/regime_share.py --hard-tether
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.sim import Disturbance, generate_trial, load_example_vehicle, load_truth  # noqa: E402
from pipeline.sim.regime import draw_regime  # noqa: E402
from pipeline.sim.vehicle import Dynamics  # noqa: E402
from pipeline.vocabulary import DOFS, acceleration_column, velocity_column  # noqa: E402

POSE = ["x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs=2, default=[6400, 6600], metavar=("FIRST", "END"))
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--hard-tether", action="store_true")
    args = ap.parse_args()
    vehicle = load_example_vehicle()
    dyn = Dynamics(vehicle, load_truth())
    first: dict = {}
    for seed in range(*args.seeds):
        first.setdefault(draw_regime(seed).kind(), seed)
    print("| regime | seed | u̇ | v̇ | ṙ |\n| --- | ---: | ---: | ---: | ---: |")
    for _kind, seed in sorted(first.items()):
        regime = draw_regime(seed)
        dist = None
        if args.hard_tether and regime.disturbance:
            dist = Disturbance.hard()
        t = generate_trial(vehicle, args.duration, seed=seed, preset="family", rate_hz=50.0, warmup_s=30.0,
                           disturbance=dist).truth
        nu = t[[velocity_column(d) for d in DOFS]].to_numpy()
        n = t[[th.speed_signal for th in vehicle.thrusters]].to_numpy()
        a = t[[acceleration_column(d) for d in DOFS]].to_numpy()[:, [0, 1, 5]]
        pred = dyn.nu_dot(t[POSE].to_numpy(), nu, n)[:, [0, 1, 5]]
        r2 = 1.0 - np.mean((pred - a) ** 2, axis=0) / np.var(a, axis=0)
        print(f"| {regime.describe()} | {seed} | " + " | ".join(f"{v:.3f}" for v in r2) + " |")


if __name__ == "__main__":
    main()
