"""The coupled study on a simulated ship (rudder, propeller thrust): ``abkowitz`` and its gray box
``graybox_abkowitz`` through the study's own model building, tuning and final check."""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.config.params import CoupledParams
from pipeline.sim.synthetic import ship_zigzag
from pipeline.studies.coupled import build_model, model_inputs, run_study

INPUTS = ["u_mps", "v_mps", "r_radps", "T_prop_N", "rudder_rad"]


def _ship_frame() -> pd.DataFrame:
    """Tuning: one run; train_test: two (zig-zags and rudder steps); test: an unseen zig-zag (other seed,
    amplitudes and thrusts). 10 Hz, so the SVRs stay quick."""
    runs = [ship_zigzag(200.0, rate_hz=10.0, seed=s, trial=f"ship{s}", manoeuvres=("zigzag", "steps"), split=split)
            for s, split in ((0, "tuning"), (1, "train_test"), (2, "train_test"))]
    runs.append(ship_zigzag(200.0, rate_hz=10.0, seed=100, trial="ship100", amplitudes_deg=(15.0, 25.0),
                            thrusts_N=(15.0, 30.0), split="test"))
    return pd.concat(runs, ignore_index=True)


def test_abkowitz_takes_the_thrust_and_the_rudder():
    params = CoupledParams(inputs=INPUTS, models=["abkowitz", "graybox_abkowitz"])
    assert model_inputs("abkowitz", params) == INPUTS
    assert model_inputs("graybox_abkowitz", params) == INPUTS
    model = build_model("abkowitz", None, params)
    assert (model.n_thrust, model.n_surfaces) == (1, 1)
    rpm = CoupledParams(inputs=["u_mps", "v_mps", "r_radps", "prop_rpm", "rudder_rad"], models=["abkowitz"])
    assert model_inputs("abkowitz", rpm) == ["u_mps", "v_mps", "r_radps", "tau_u_N", "rudder_rad"]


def test_ship_study_manoeuvring_family_and_its_gray_box():
    params = CoupledParams(inputs=INPUTS, models=["abkowitz", "graybox_abkowitz"], tuning="split", folds=2,
                           max_evals=6, max_samples=300, n_jobs=1)
    out = run_study(_ship_frame(), params)
    assert not out["failed"]
    final = {m: np.array([out["results"][m]["final"][o]["r2"] for o in params.outputs])
             for m in params.models}
    assert np.all(final["abkowitz"] >= 0.9), final
    assert np.all(final["graybox_abkowitz"] >= final["abkowitz"]), final  # each residual kept only where it helps
    base = out["results"]["abkowitz"]["estimator"]
    assert set(base.selected_terms_) >= {"Y_d", "Y_Td", "N_d", "N_Td", "X_T"}
