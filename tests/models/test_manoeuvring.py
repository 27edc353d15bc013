"""The Abkowitz-type manoeuvring model on a simulated ship whose true forces are in its family
(pipeline.sim.synthetic.SHIP_TRUTH): coefficients, term selection, an unseen zig-zag."""

from __future__ import annotations

import functools

import numpy as np
import pandas as pd
import pytest
from sklearn.base import clone

from pipeline.models.manoeuvring import TERMS, Abkowitz3DOF
from pipeline.sim.synthetic import SHIP_TRUTH, ship_zigzag

INPUTS = ["u_mps", "v_mps", "r_radps", "T_prop_N", "rudder_rad"]
OUTPUTS = ["udot_mps2", "vdot_mps2", "rdot_radps2"]
TRAIN_SEEDS = (0, 1, 2)  # fitting: zig-zags and rudder steps
UNSEEN_SEED = 100  # the unseen zig-zag: other amplitudes, other thrusts, pure zig-zag


@functools.lru_cache(maxsize=4)
def _training(noise: float = 0.1) -> pd.DataFrame:
    return pd.concat([ship_zigzag(300.0, seed=s, trial=f"ship{s}", manoeuvres=("zigzag", "steps"), noise=noise)
                      for s in TRAIN_SEEDS], ignore_index=True)


@functools.lru_cache(maxsize=1)
def _fitted(noise: float = 0.1) -> Abkowitz3DOF:
    frame = _training(noise)
    return Abkowitz3DOF().fit(frame[INPUTS].to_numpy(), frame[OUTPUTS].to_numpy())


def _r2(y: np.ndarray, p: np.ndarray) -> np.ndarray:
    return 1.0 - ((y - p) ** 2).sum(0) / ((y - y.mean(0)) ** 2).sum(0)


def test_truth_is_in_the_family():
    assert set(SHIP_TRUTH) <= set(Abkowitz3DOF.names())
    absent = set(Abkowitz3DOF.names()) - set(SHIP_TRUTH)
    assert {"X_0", "X_u", "Y_0", "Y_vvr", "N_|v|v", "N_ddd"} <= absent  # something for the selection to drop


def test_noise_free_recovers_the_truth_exactly():
    model = _fitted(0.0)
    coef = model.coefficients()
    for name, value in coef.items():
        assert value == pytest.approx(SHIP_TRUTH.get(name, 0.0), rel=1e-6, abs=1e-9), name
    assert set(model.selected_terms_) == set(SHIP_TRUTH)


def test_noisy_fit_recovers_every_coefficient_within_10_percent():
    coef = _fitted().coefficients()
    errors = {k: abs(coef[k] - v) / abs(v) for k, v in SHIP_TRUTH.items()}
    assert max(errors.values()) < 0.10, errors
    assert np.mean(list(errors.values())) < 0.03, errors


def test_selection_drops_the_terms_not_in_the_truth():
    model = _fitted()
    assert set(model.selected_terms_) == set(SHIP_TRUTH)
    assert all(v == 0.0 for k, v in model.coefficients().items() if k not in SHIP_TRUTH)
    removed = [r["removed"] for r in model.selection_ if r["removed"]]
    assert set(removed) == set(Abkowitz3DOF.names()) - set(SHIP_TRUTH)


def test_unseen_zigzag_scores_at_least_0_9_per_dof():
    unseen = ship_zigzag(300.0, seed=UNSEEN_SEED, amplitudes_deg=(15.0, 25.0), thrusts_N=(15.0, 30.0))
    pred = _fitted().predict(unseen[INPUTS].to_numpy())
    assert np.all(_r2(unseen[OUTPUTS].to_numpy(), pred) >= 0.9)
    assert np.all(_r2(unseen[[f"true_{o}" for o in OUTPUTS]].to_numpy(), pred) >= 0.99)


def test_without_the_rudder_its_terms_are_dropped_with_a_warning(caplog):
    frame = _training()
    model = Abkowitz3DOF(n_surfaces=0).fit(frame[INPUTS[:4]].to_numpy(), frame[OUTPUTS].to_numpy())
    rudder = [f"{eq}_{t}" for eq in TERMS for t in TERMS[eq] if "d" in t]
    assert set(model.dropped_terms_) == set(rudder)
    assert not set(model.selected_terms_) & set(rudder)
    assert "no excitation" in caplog.text


def test_two_rudders_act_as_one_and_two_propellers_add():
    frame = _training()
    X = frame[INPUTS].to_numpy()
    X2 = np.column_stack([X[:, :3], 0.5 * X[:, 3], 0.5 * X[:, 3], X[:, 4], X[:, 4]])
    model = Abkowitz3DOF(n_thrust=2, n_surfaces=2).fit(X2, frame[OUTPUTS].to_numpy())
    assert model.coefficients() == pytest.approx(_fitted().coefficients(), rel=1e-9, abs=1e-12)


def test_bad_inputs_are_named():
    frame = _training()
    with pytest.raises(ValueError, match=r"\[u v r\] \+ 1 thrust \+ 1 control-surface"):
        Abkowitz3DOF().fit(frame[INPUTS[:4]].to_numpy(), frame[OUTPUTS].to_numpy())
    with pytest.raises(ValueError, match="unknown Abkowitz term"):
        Abkowitz3DOF(terms=["Y_vv"]).fit(frame[INPUTS].to_numpy(), frame[OUTPUTS].to_numpy())


def test_offered_terms_and_clone():
    frame = _training()
    model = clone(Abkowitz3DOF(terms=sorted(SHIP_TRUTH), select=False))
    model.fit(frame[INPUTS].to_numpy(), frame[OUTPUTS].to_numpy())
    assert set(model.selected_terms_) == set(SHIP_TRUTH)
    fast = model.fast_predictor()
    X = frame[INPUTS].to_numpy()[:50]
    np.testing.assert_array_equal(fast(X), model.predict(X))
