"""Extrapolation diagnostics (pipeline.studies.coverage) on simulated trials: is a test trial of the training's own
regime flagged, and one of another regime?

    python bench/input_coverage.py                      # 480-s trials, seeds 1-3 of each preset (docs/models.md)
    python bench/input_coverage.py --duration 960 --seeds 1 2

Each trial is one run of the project's simulator (``generate_trial(..., preset=...)``: gentle = three sines per
thruster, periods 6-45 s, 2600 rpm; hard = one sine, 5-18 s, 1800 rpm), its truth table taken at 10 Hz (the true
velocities and thrusts: what the diagnostics see apart from estimation noise). Each preset's first seed is the one
training trial; every other trial is a test trial. Prints one markdown row per (training trial, input set, test
trial): the inputs named with their share outside the training range and largest excess in training SDs, the share
beyond the hull, the share of samples flagged as extrapolations, and the inputs listed as least excited.
"""

from __future__ import annotations

import argparse
import logging

import pandas as pd

from pipeline.sim import generate_trial, load_example_vehicle
from pipeline.studies.coverage import study_coverage

INPUT_SETS = {"SVRs": ["u_mps", "v_mps", "r_radps", "T_th1_N", "T_th2_N", "T_th3_N"],
              "explicit": ["u_mps", "v_mps", "r_radps", "tau_u_N", "tau_v_N", "tau_r_Nm"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=480.0, help="seconds per trial")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="simulator seeds per preset")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # the study logs each flagged trial; the table says it
    vehicle = load_example_vehicle()
    trials = {f"{p}{s}": generate_trial(vehicle, args.duration, seed=s, preset=p).truth.iloc[::20].assign(
        trial=f"{p}{s}") for p in ("gentle", "hard") for s in args.seeds}
    print("| training | inputs | test trial | named: share outside, largest excess | beyond hull | flagged "
          "| least excited |")
    print("| --- | --- | --- | --- | ---: | ---: | --- |")
    for train in (f"gentle{args.seeds[0]}", f"hard{args.seeds[0]}"):
        tests = pd.concat([t for n, t in trials.items() if n != train], ignore_index=True)
        doc = study_coverage(trials[train], tests, INPUT_SETS)
        for group, name in zip(doc["groups"], INPUT_SETS, strict=True):
            least = ", ".join(group["excitation"]["least_excited"]) or "none"
            for trial, e in group["trials"].items():
                named = "; ".join(f"{d['input']} {100 * d['share_outside_range']:.0f} %, {d['max_excess_sd']:.1f} SD"
                                  for d in e["inputs"] if d["extrapolated"]) or "none"
                print(f"| {train} | {name} | {trial} | {named} | {100 * e['hull']['share_beyond']:.1f} % "
                      f"| {100 * e['extrapolated_share']:.1f} % | {least} |")


if __name__ == "__main__":
    main()
