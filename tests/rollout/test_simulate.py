"""Free-run simulation: integrator against a known plant, gaps, divergence detection, horizons, GP band."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline import physics
from pipeline.models.decoupled import DampingGP, LinearQuadraticDamping
from pipeline.report.rollout import plot_free_runs
from pipeline.rollout import (
    CoupledDynamics,
    DecoupledDynamics,
    Table1D,
    band_tables,
    damping_tables,
    free_run,
    horizon_errors,
    table_range,
)
from pipeline.sim.synthetic import SyntheticPlant, synthetic_trial
from pipeline.vocabulary import TAU_COLUMNS, VELOCITY_COLUMNS

DOFS = ["u", "v", "r"]
PLANT = SyntheticPlant()


@pytest.fixture(scope="module")
def trial() -> pd.DataFrame:
    return synthetic_trial(PLANT, duration_s=120.0, seed=2, gap_s=(60.0, 65.0))


def arrays(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    return (df["t_ns"].to_numpy(), df[[VELOCITY_COLUMNS[d] for d in DOFS]].to_numpy(),
            df[[TAU_COLUMNS[d] for d in DOFS]].to_numpy(), df["segment"].to_numpy())


def fitted(df: pd.DataFrame, model: object) -> dict[str, object]:
    ok = df["segment"] >= 0
    return {d: type(model)(**model.get_params()).fit(df.loc[ok, [VELOCITY_COLUMNS[d]]].to_numpy(),
                                                     df.loc[ok, f"d_{d}_{'Nm' if d == 'r' else 'N'}"].to_numpy())
            for d in DOFS}


def test_coriolis_probe_matches_physics() -> None:
    rng = np.random.default_rng(0)
    A = rng.standard_normal((6, 6))
    M = A @ A.T + 6 * np.eye(6)
    f = DecoupledDynamics(M, DOFS, {d: np.zeros_like for d in DOFS}, physics.coriolis_force)
    assert f.Q is not None
    nu = rng.standard_normal((5, 3))
    nu6 = np.zeros((5, 6))
    nu6[:, [0, 1, 5]] = nu
    expected = -physics.coriolis_force(M, nu6)[:, [0, 1, 5]] @ np.linalg.inv(M[np.ix_([0, 1, 5], [0, 1, 5])]).T
    np.testing.assert_allclose(f(nu, np.zeros((5, 3))), expected, rtol=1e-9, atol=1e-12)


def test_table_matches_the_model_far_below_the_noise() -> None:
    x = np.linspace(-1, 1, 400)
    gp = DampingGP(max_samples=100).fit(x[:, None], PLANT.damping("v", x))
    table = Table1D.from_model(gp, *table_range(x))
    probe = np.linspace(-0.99, 0.99, 997)
    exact = gp.predict(probe[:, None])
    assert np.max(np.abs(table(probe) - exact)) < 1e-5 * np.ptp(exact)


def test_free_run_of_the_true_plant_tracks_measurement_and_restarts_after_gaps(trial: pd.DataFrame) -> None:
    t_ns, nu, tau, seg = arrays(trial)
    run = free_run("truth", PLANT.as_dynamics(), t_ns, nu, tau, DOFS, segment=seg)
    assert run.status == "ok" and run.diverged_at_s is None
    gap = seg < 0
    assert np.isnan(run.predicted[gap]).all() and np.isfinite(run.predicted[~gap]).all()
    assert run.predicted[~gap][0] == pytest.approx(nu[0])
    first_after = np.flatnonzero(~gap & (np.arange(len(seg)) > np.flatnonzero(gap)[-1]))[0]
    np.testing.assert_allclose(run.predicted[first_after], nu[first_after])  # re-initialized from measurement
    for d in DOFS:
        assert run.metrics[d]["mae"] < 0.01 and run.metrics[d]["r2"] > 0.99


def test_unstable_model_divergence_is_detected_and_plotted(trial: pd.DataFrame, tmp_path) -> None:
    t_ns, nu, tau, seg = arrays(trial)
    unstable = LinearQuadraticDamping().fit(np.c_[[-1.0, 1.0]], [10.0, -10.0])  # negative damping
    f = DecoupledDynamics(PLANT.mass_matrix(), DOFS, damping_tables({d: unstable for d in DOFS},
                                                                    {d: (-3, 3) for d in DOFS}), physics.coriolis_force)
    run = free_run("unstable", f, t_ns, nu, tau, DOFS, segment=seg, divergence_factor=5.0)
    assert run.status == "diverged" and 0 < run.diverged_at_s < 60
    assert not np.isinf(run.predicted).any()
    ok = np.isfinite(run.predicted)
    assert np.all(np.abs(run.predicted[ok]) <= 5.0 * np.abs(nu).max(axis=0)[None].repeat(len(nu), 0)[ok])
    assert run.summary()["status"] == "diverged"
    truth = free_run("truth", PLANT.as_dynamics(), t_ns, nu, tau, DOFS, segment=seg)
    png = plot_free_runs([truth, run], tmp_path / "free_run.png")
    assert png.stat().st_size > 10_000


def test_horizon_errors_grow_for_an_imperfect_model(trial: pd.DataFrame) -> None:
    t_ns, nu, tau, seg = arrays(trial)
    tables = {d: (lambda x, d=d: 0.6 * PLANT.damping(d, x)) for d in DOFS}  # 40 % too little damping
    f = DecoupledDynamics(PLANT.mass_matrix(), DOFS, tables, physics.coriolis_force)
    out = horizon_errors(f, t_ns, nu, tau, DOFS, [1.0, 5.0, 10.0], segment=seg)
    assert out["10"]["n_windows"] == 10 and out["1"]["n_windows"] > 100  # 60 s + 55 s runs around the gap
    for d in ("u", "v"):  # grows with the horizon, then saturates (yaw's time constant is below 1 s)
        assert out["1"]["mae_window"][d] < out["5"]["mae_window"][d] < 1.5 * out["10"]["mae_window"][d]
    exact = horizon_errors(PLANT.as_dynamics(), t_ns, nu, tau, DOFS, [10.0], segment=seg)
    assert exact["10"]["mae_end"]["u"] < 0.2 * out["10"]["mae_end"]["u"]


def test_gp_band_covers_the_measured_velocity(trial: pd.DataFrame) -> None:
    t_ns, nu, tau, seg = arrays(trial)
    gps = fitted(trial, DampingGP(max_samples=150))
    ranges = {d: table_range(nu[:, j]) for j, d in enumerate(DOFS)}
    M = PLANT.mass_matrix()
    f = DecoupledDynamics(M, DOFS, damping_tables(gps, ranges), physics.coriolis_force)
    band = DecoupledDynamics(M, DOFS, band_tables(gps, ranges, 8, seed=0), physics.coriolis_force)
    run = free_run("gp", f, t_ns, nu, tau, DOFS, segment=seg, band_f=band, band_members=8)
    cover = run.summary()["band_coverage"]
    assert run.status == "ok" and all(run.metrics[d]["r2"] > 0.95 for d in DOFS)
    assert all(c > 0.5 for c in cover.values()), cover
    again = free_run("gp", f, t_ns, nu, tau, DOFS, segment=seg, band_f=band, band_members=8)
    np.testing.assert_array_equal(again.band[0], run.band[0])  # deterministic


class TruthAcceleration:
    """A 'coupled' estimator: predict([u v r n1 n2 n3]) -> [udot vdot rdot] from the plant itself."""

    f = PLANT.as_dynamics()

    def predict(self, X: np.ndarray) -> np.ndarray:
        return self.f(X[:, :3], PLANT.tau(X[:, 3:]))


def test_coupled_protocol_free_run(trial: pd.DataFrame) -> None:
    t_ns, nu, _, seg = arrays(trial)
    rpm = trial[["n1_rpm", "n2_rpm", "n3_rpm"]].to_numpy()
    run = free_run("coupled", CoupledDynamics(TruthAcceleration()), t_ns, nu, rpm, DOFS, segment=seg)
    assert run.status == "ok" and run.metrics["u"]["mae"] < 0.01


def test_figure_axis_labels_name_the_unit() -> None:
    """Every study figure labels its axes from the column's unit suffix (issue 16: "u [m/s]", not u_mps)."""
    from pipeline.units import axis_label

    assert axis_label("u_mps") == "u [m/s]" and axis_label("r_radps") == "r [rad/s]"
    assert axis_label("udot_mps2") == "u\u0307 [m/s²]" and axis_label("rdot_radps2") == "r\u0307 [rad/s²]"
    assert axis_label("d_u_N") == "d_u [N]" and axis_label("d_r_Nm") == "d_r [N·m]"
    assert axis_label("segment") == "segment"  # no unit suffix: unchanged
