"""DVL-outage bridging: dead reckoning, and a learned model beats holding the last DVL velocity."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.models.decoupled import make_estimator
from pipeline.physics import coriolis_force
from pipeline.report.rollout import bridging_markdown, plot_bridging
from pipeline.rollout import DecoupledDynamics, bridge_outages, damping_tables, dead_reckon, table_range
from pipeline.sim.synthetic import SyntheticPlant, synthetic_trial
from pipeline.vocabulary import TAU_COLUMNS, VELOCITY_COLUMNS

DOFS = ["u", "v", "r"]
PLANT = SyntheticPlant()


def test_dead_reckoning_in_ned() -> None:
    n = 11
    pos = dead_reckon(np.ones(n), np.zeros(n), np.full(n, np.pi / 2), 0.1)  # 1 m/s forward, heading east
    assert pos[-1] == pytest.approx([0.0, 1.0], abs=1e-12)
    pos = dead_reckon(np.zeros(n), np.ones(n), np.zeros(n), 0.1)  # sway to starboard, heading north
    assert pos[-1] == pytest.approx([0.0, 1.0], abs=1e-12)


def test_learned_model_beats_hold_last_velocity_on_30s_outages(tmp_path) -> None:
    train = synthetic_trial(PLANT, duration_s=150.0, seed=5)
    test = synthetic_trial(PLANT, duration_s=150.0, seed=6)
    t_ns = test["t_ns"].to_numpy()
    nu = test[[VELOCITY_COLUMNS[d] for d in DOFS]].to_numpy()
    tau = test[[TAU_COLUMNS[d] for d in DOFS]].to_numpy()
    ranges = {d: table_range(nu[:, j]) for j, d in enumerate(DOFS)}
    models = {}
    for name in ("ls", "krr"):
        fitted = {}
        for d in DOFS:
            est = make_estimator(name)
            if name == "krr":
                est.set_params(krr__alpha=1e-2, krr__gamma=1.0)
            rows = slice(None, None, 4)
            fitted[d] = est.fit(train[[VELOCITY_COLUMNS[d]]].to_numpy()[rows],
                                train[f"d_{d}_{'Nm' if d == 'r' else 'N'}"].to_numpy()[rows])
        models[name] = DecoupledDynamics(PLANT.mass_matrix(), DOFS, damping_tables(fitted, ranges),
                                         coriolis_force)
    models["truth"] = PLANT.as_dynamics()
    rows = bridge_outages(models, t_ns, nu, tau, test["yaw_rad"].to_numpy(), DOFS, [10.0, 30.0])
    err = {(r["window_s"], r["model"]): r["mean_error_m"] for r in rows}
    assert {r["n_windows"] for r in rows if r["window_s"] == 30.0} == {4}
    assert err[(30.0, "krr")] < 0.5 * err[(30.0, "hold_last")]
    assert err[(30.0, "truth")] < 0.1
    assert min(err[(30.0, "krr")], err[(30.0, "ls")]) < err[(30.0, "hold_last")]
    md = bridging_markdown(rows)
    assert "| 30 | hold_last |" in md
    assert plot_bridging(rows, tmp_path / "bridging.png").stat().st_size > 5_000
