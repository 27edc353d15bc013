"""State estimation with known answers: noise estimates, the banded RTS smoother against the textbook recursion,
lock-loss bridging, maximum-likelihood process noise, gating, auto widths, and the kalman method end to end."""

from __future__ import annotations

import decimal

import numpy as np
import pytest

from pipeline.estimation.noise import NOISE_FLOOR, estimate_noise
from pipeline.estimation.smoother import Measurements, memory_s, smooth, smoothed_variances, white_jerk
from pipeline.estimation.widths import optimal_sigma

H_S = 0.1
H_NS = 100_000_000


def _signal(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = 0.4 * np.sin(0.35 * t + 0.3) + 0.15 * np.sin(1.3 * t) + 0.05 * t
    xdot = 0.4 * 0.35 * np.cos(0.35 * t + 0.3) + 0.15 * 1.3 * np.cos(1.3 * t) + 0.05
    return x, xdot


@pytest.mark.parametrize("sd", [0.02, 0.002])
def test_noise_estimate_within_10_percent_on_irregular_stamps(sd: float) -> None:
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.25, 0.31, 4000))
    x, _ = _signal(t)
    y = x + sd * rng.standard_normal(t.size)
    y[rng.uniform(size=t.size) < 0.005] += 10 * sd  # outliers must not inflate it
    est = estimate_noise(t, y)
    assert est.sd == pytest.approx(sd, rel=0.10)
    assert 0.002 < est.outlier_rate < 0.008


def test_noise_free_and_constant_signals_get_the_floor_never_zero_or_rounding() -> None:
    """A noise-free signal's residuals are float rounding (~1e-18) or exactly 0: the estimate is the floor, marked
    as such; large values lift it above their rounding; a real sensor's noise is untouched by it."""
    t = np.arange(600) * 0.25
    for x in (np.zeros(t.size), np.full(t.size, 0.05), np.full(t.size, -0.3)):
        est = estimate_noise(t, x)
        assert est.sd == NOISE_FLOOR and est.source == "floor" and est.outlier_rate == 0.0
    est = estimate_noise(t, 5e6 + np.zeros(t.size))  # a UTM northing standing still
    assert est.sd == pytest.approx(5e-6) and est.source == "floor"
    noisy = estimate_noise(t, np.cos(t / 10) + 1e-6 * np.random.default_rng(1).standard_normal(t.size))
    assert noisy.source == "estimated" and noisy.sd == pytest.approx(1e-6, rel=0.15)


def test_noise_estimate_skips_gaps() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(3000) * 0.1
    x, _ = _signal(t)
    y = x + 0.01 * rng.standard_normal(t.size)
    y[1000:1050] = np.nan   # a gap: residuals next to it would straddle it
    t = np.delete(t, np.s_[2000:2040])  # and a jump in time
    y = np.delete(y, np.s_[2000:2040])
    assert estimate_noise(t, y).sd == pytest.approx(0.01, rel=0.10)


def _textbook_rts(grid_s: np.ndarray, meas_k: np.ndarray, y: np.ndarray, r: float, q: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Kalman filter + RTS smoother written step by step, measurements at grid steps ``meas_k``."""
    phi, Q = white_jerk(H_S, q)
    S_inv = np.diag([1.0, 1.0 / H_S, 1.0 / H_S**2])
    P = S_inv @ (1e10 * np.eye(3)) @ S_inv  # the smoother's diffuse prior (precision 1e-10, scaled states)
    x = np.zeros(3)
    Hm = np.array([[1.0, 0.0, 0.0]])
    n = grid_s.size
    xf, Pf, xp, Pp = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 3, 3))
    obs = dict(zip(meas_k.tolist(), y.tolist(), strict=True))
    for k in range(n):
        if k:
            x, P = phi @ x, phi @ P @ phi.T + Q
        xp[k], Pp[k] = x, P
        if k in obs:
            s = (Hm @ P @ Hm.T).item() + r
            gain = (P @ Hm.T / s)[:, 0]
            x = x + gain * (obs[k] - x[0])
            P = P - np.outer(gain, Hm @ P)
        xf[k], Pf[k] = x, P
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(n - 2, -1, -1):
        C = Pf[k] @ phi.T @ np.linalg.inv(Pp[k + 1])
        xs[k] = xf[k] + C @ (xs[k + 1] - xp[k + 1])
        Ps[k] = Pf[k] + C @ (Ps[k + 1] - Pp[k + 1]) @ C.T
    return xs, Ps


def test_banded_smoother_is_the_textbook_rts_and_bridges_a_3_s_lock_loss() -> None:
    rng = np.random.default_rng(6)
    n = 600
    grid = np.arange(n, dtype=np.int64) * H_NS
    t = grid / 1e9
    keep = np.ones(n, dtype=bool)
    keep[::3] = False                # a slower sensor: two steps of three
    keep[300:330] = False            # 3 s without bottom lock
    k = np.flatnonzero(keep)
    x, _ = _signal(t)
    r, q = 0.02**2, 0.05
    y = x[k] + 0.02 * rng.standard_normal(k.size)
    got = smooth(grid, Measurements(grid[k], y, r), q=q, gate=0)
    smoothed_variances([got])
    xs, Ps = _textbook_rts(t, k, y, r, q)
    # after 6 s: the textbook filter's diffuse start (P0 = 1e10) costs it digits for the first seconds
    ok = slice(60, None)
    np.testing.assert_allclose(got.x[ok], xs[ok, 0], atol=1e-8)
    np.testing.assert_allclose(got.xdot[ok], xs[ok, 1], atol=1e-7)
    np.testing.assert_allclose(got.x_sd[ok], np.sqrt(Ps[ok, 0, 0]), rtol=1e-5)
    np.testing.assert_allclose(got.xdot_sd[ok], np.sqrt(Ps[ok, 1, 1]), rtol=1e-5)
    # the variance grows into the gap and shrinks out of it, largest in its middle, far above the measured parts
    gap = got.x_sd[299:331]
    mid = int(np.argmax(gap))
    assert 12 <= mid <= 20
    assert np.all(np.diff(gap[: mid + 1]) > 0) and np.all(np.diff(gap[mid:]) < 0)
    assert gap.max() > 4 * np.median(got.x_sd[50:250])


def test_chunked_variances_equal_the_single_pass() -> None:
    rng = np.random.default_rng(7)
    n = 5000
    grid = np.arange(n, dtype=np.int64) * H_NS
    tm = np.sort(rng.uniform(0, (n - 1) * H_S, 1500))
    tm = tm[(tm < 100) | (tm > 104)]   # a 4-s gap
    x, _ = _signal(tm)
    meas = Measurements((tm * 1e9).astype(np.int64), x + 0.02 * rng.standard_normal(tm.size), 0.02**2)
    a, b = smooth(grid, meas), smooth(grid, meas)
    smoothed_variances([a], burn_s=1e9)
    smoothed_variances([b])  # the defaults: many chunks
    np.testing.assert_allclose(b.x_sd, a.x_sd, rtol=1e-5)
    np.testing.assert_allclose(b.xdot_sd, a.xdot_sd, rtol=1e-5)


def test_chunked_variances_equal_the_single_pass_when_the_smoother_remembers_long() -> None:
    """A DVL-like DOF (3.3 Hz, 2 cm/s) whose smoother is far smoother than the measurements are dense (q 4e-8:
    a memory of about 4 s, beyond 40 measurement intervals): each chunk's burn-in must cover that memory, or the
    chunked SDs are off by up to a few per cent. The single pass is exact (the test below)."""
    rng = np.random.default_rng(11)
    n = 6000
    grid = np.arange(n, dtype=np.int64) * H_NS
    tm = np.sort(rng.uniform(0, (n - 1) * H_S, int(0.33 * n)))
    meas = Measurements((tm * 1e9).astype(np.int64), 0.02 * rng.standard_normal(tm.size), 0.02**2)
    a, b = smooth(grid, meas, q=4e-8, s=4e-5, gate=0), smooth(grid, meas, q=4e-8, s=4e-5, gate=0)
    smoothed_variances([a], burn_s=1e9)
    smoothed_variances([b])  # the defaults: several chunks, each with a burn-in over the smoother's memory
    assert memory_s(b) == pytest.approx(3.8, rel=0.1)
    np.testing.assert_allclose(b.xdot_sd, a.xdot_sd, rtol=1e-4)
    np.testing.assert_allclose(b.xddot_sd, a.xddot_sd, rtol=1e-4)


def _rts_variances_in_80_digits(n: int, meas_k: np.ndarray, r: float, q: float) -> np.ndarray:
    """Smoothed variances of (x, x', x''), cov(x, x') and cov(x_k, x_k+2) of the white-jerk model (columns 0-4),
    measurements of x at grid steps ``meas_k``:
    a Kalman filter + RTS smoother written step by step (Särkkä 2013, eqs. 4.20-4.21 and Th. 8.2) in 80-digit
    decimal arithmetic, with the smoother's own diffuse prior (precision 1e-10 on the scaled states), so that no
    rounding of float64 can reach the reference."""
    with decimal.localcontext() as ctx:
        ctx.prec = 80
        D = decimal.Decimal
        h = D(H_NS) / D(10**9)
        phi = [[D(1), h, h * h / 2], [D(0), D(1), h], [D(0), D(0), D(1)]]
        qd = D(repr(q))
        Q = [[qd * h**5 / 20, qd * h**4 / 8, qd * h**3 / 6], [qd * h**4 / 8, qd * h**3 / 3, qd * h**2 / 2],
             [qd * h**3 / 6, qd * h**2 / 2, qd * h]]

        def mul(a, b, bt=False):
            return [[sum(a[i][m] * (b[j][m] if bt else b[m][j]) for m in range(3)) for j in range(3)] for i in range(3)]

        def inv(a):
            adj = [[a[(j + 1) % 3][(i + 1) % 3] * a[(j + 2) % 3][(i + 2) % 3]
                    - a[(j + 1) % 3][(i + 2) % 3] * a[(j + 2) % 3][(i + 1) % 3] for j in range(3)] for i in range(3)]
            det = sum(a[0][m] * adj[m][0] for m in range(3))
            return [[adj[i][j] / det for j in range(3)] for i in range(3)]

        scale = [D(1), h, h * h]  # the smoother's prior: precision 1e-10 on (x, h x', h^2 x'')
        P = [[(D(10) ** 10 / (scale[i] * scale[i]) if i == j else D(0)) for j in range(3)] for i in range(3)]
        measured = set(meas_k.tolist())
        rd = D(repr(r))
        Pf, Pp = [], []
        for k in range(n):
            if k:
                P = [[a + b for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(mul(mul(phi, P), phi, bt=True), Q,
                                                                                  strict=True)]
            Pp.append(P)
            if k in measured:
                s = P[0][0] + rd
                P = [[P[i][j] - P[i][0] * P[0][j] / s for j in range(3)] for i in range(3)]
            Pf.append(P)
        out = np.zeros((n, 5))
        sig = Pf[-1]
        out[-1, :4] = [float(sig[0][0]), float(sig[1][1]), float(sig[2][2]), float(sig[0][1])]
        lag1 = None  # cov(z_k+1, z_k+2) = C_k+1 Sigma_k+2 (the smoothed cross-covariance)
        for k in range(n - 2, -1, -1):
            C = mul(mul(Pf[k], phi, bt=True), inv(Pp[k + 1]))
            if lag1 is not None:
                out[k, 4] = float(mul(C, lag1)[0][0])
            lag1 = mul(C, sig)
            d = [[a - b for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(sig, Pp[k + 1], strict=True)]
            sig = [[a + b for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(Pf[k], mul(mul(C, d), C, bt=True),
                                                                              strict=True)]
            out[k, :4] = [float(sig[0][0]), float(sig[1][1]), float(sig[2][2]), float(sig[0][1])]
    return out


def test_variances_are_exact_for_a_smoother_far_smoother_than_its_measurements() -> None:
    """The demo's kinematic pass on the DVL's axes: q 5e-8, 2 cm/s every third 0.1-s step, no input (s = 0). The
    process precision per step is some 1e12 times the measurements' information, which an information-form
    recursion cancels to 0.2-2 %; the variances must match an 80-digit RTS smoother to 1e-6, in one pass and
    chunked."""
    n, r, q = 900, 0.02**2, 5e-8
    grid = np.arange(n, dtype=np.int64) * H_NS
    k = np.arange(0, n, 3)
    k = k[(k < 400) | (k > 430)]  # and 3 s without bottom lock
    y = 0.3 + 0.02 * np.random.default_rng(12).standard_normal(k.size)
    exact = _rts_variances_in_80_digits(n, k, r, q)
    for burn_s in (1e9, 2.0):
        got = smooth(grid, Measurements(grid[k], y, r), q=q, gate=0)
        smoothed_variances([got], burn_s=burn_s)
        np.testing.assert_allclose(got.x_sd, np.sqrt(exact[:, 0]), rtol=1e-6)
        np.testing.assert_allclose(got.xdot_sd, np.sqrt(exact[:, 1]), rtol=1e-6)
        np.testing.assert_allclose(got.xddot_sd, np.sqrt(exact[:, 2]), rtol=1e-6)
        np.testing.assert_allclose(got.x_xdot_cov, exact[:, 3], rtol=1e-6, atol=1e-6 * np.abs(exact[:, 3]).max())
        np.testing.assert_allclose(got.x_lag2_cov[: n - 2], exact[: n - 2, 4], rtol=1e-6)


def test_maximum_likelihood_recovers_the_process_noise() -> None:
    """Data drawn from the white-jerk model itself: the ML q is near the true one."""
    rng = np.random.default_rng(8)
    n, q_true = 20_000, 0.5
    phi, Q = white_jerk(H_S, q_true)
    L = np.linalg.cholesky(Q)
    state = np.zeros((n, 3))
    for k in range(1, n):
        state[k] = phi @ state[k - 1] + L @ rng.standard_normal(3)
    grid = np.arange(n, dtype=np.int64) * H_NS
    y = state[:, 0] + 0.01 * rng.standard_normal(n)
    res = smooth(grid, Measurements(grid, y, 0.01**2), gate=0)
    assert res.q == pytest.approx(q_true, rel=0.25)


def test_noise_free_trajectory_gives_exact_derivative_away_from_edges() -> None:
    """A smooth trajectory sampled without noise at 100 Hz (the noise estimate is then ~0)."""
    grid = np.arange(0, 3001, dtype=np.int64) * 10_000_000  # 30 s at 100 Hz
    t = grid / 1e9
    x, xdot = _signal(t)
    sd = estimate_noise(t, x).sd
    assert sd < 1e-6
    res = smooth(grid, Measurements(grid, x, max(sd, 1e-9) ** 2))
    inner = slice(100, -100)
    np.testing.assert_allclose(res.x[inner], x[inner], atol=1e-7)
    np.testing.assert_allclose(res.xdot[inner], xdot[inner], atol=1e-4)


def test_gating_rejects_outliers() -> None:
    rng = np.random.default_rng(9)
    grid = np.arange(3000, dtype=np.int64) * H_NS
    t = grid / 1e9
    x, xdot = _signal(t)
    y = x + 0.01 * rng.standard_normal(t.size)
    bad = np.arange(50, 3000, 250)
    y[bad] += 0.3
    gated = smooth(grid, Measurements(grid, y, 0.01**2))
    plain = smooth(grid, Measurements(grid, y, 0.01**2), gate=0)
    assert gated.gated >= bad.size
    assert gated.gated < 2 * bad.size
    assert np.abs(gated.x - x)[bad].max() < 0.3 * np.abs(plain.x - x)[bad].max()


def test_measurements_between_grid_steps_use_their_own_stamps() -> None:
    """A DVL-like sensor whose pings fall between grid steps: a ramp is recovered exactly."""
    grid = np.arange(400, dtype=np.int64) * H_NS
    tm = np.arange(0.037, 39.9, 0.273)
    y = 0.2 + 0.03 * tm
    # pings snapped to the nearest grid step would miss by ~2e-3 here; the declared noise SD (1e-5) bounds the
    # error of a smoother that uses each ping at its own stamp (a noise SD of 1e-4 let the ML process noise leave
    # errors of 2e-5: within that SD, but not a test of the stamps)
    res = smooth(grid, Measurements((tm * 1e9).astype(np.int64), y, 1e-10), gate=0)
    np.testing.assert_allclose(res.x[5:-5], 0.2 + 0.03 * grid[5:-5] / 1e9, atol=1e-5)
    np.testing.assert_allclose(res.xdot[5:-5], 0.03, atol=1e-5)


def test_auto_width_is_near_the_best_width() -> None:
    """The plug-in width's derivative error is within 15 % of the best width's (found against the truth)."""
    from pipeline.estimation.gaussian import gaussian_filters

    rng = np.random.default_rng(10)
    dt = 0.05
    t = np.arange(0, 600, dt)
    x, xdot = _signal(t)
    y = x + 0.02 * rng.standard_normal(t.size)
    sigma = optimal_sigma([y], dt, 0.02, dt)

    def err(s: float) -> float:
        d = gaussian_filters(y, dt, s, degree=2, truncate=3.0)[1]
        return float(np.sqrt(np.mean((d - xdot)[200:-200] ** 2)))

    best = min(err(s) for s in np.linspace(0.1, 2.0, 40))
    assert err(sigma) <= 1.15 * best


@pytest.fixture(scope="module")
def realistic():
    """A 240-s DAGON trial with the simulator's default, realistic sensors (3.6 Hz DVL, 0.02 m/s noise, ...)."""
    from pipeline.sim import generate_trial, load_example_vehicle

    vehicle = load_example_vehicle()
    return vehicle, generate_trial(vehicle, 240.0, seed=3, warmup_s=20.0)


def test_kalman_method_on_a_realistic_trial(realistic) -> None:
    from pipeline.config import Params
    from pipeline.derive import derive
    from pipeline.estimation.differentiate import differentiate
    from pipeline.sync import synchronize
    from tests.store.test_stages_features import signal_tables

    vehicle, trial = realistic
    params = Params()
    assert params.differentiate.method == "kalman"  # the default
    tables = signal_tables(trial, vehicle)
    synced = synchronize(tables, vehicle, params.sync)
    kin, report = differentiate(synced, vehicle, params.differentiate, tables)
    # the noise of each sensor, estimated from the data: DVL 0.02 m/s per axis, FOG 2e-4 rad/s
    for axis in ("dvl_x_mps", "dvl_y_mps", "dvl_z_mps"):
        assert report["noise"][axis]["sd"] == pytest.approx(0.02, rel=0.15), axis
    assert report["noise"]["r_fog_radps"]["sd"] == pytest.approx(2e-4, rel=0.15)
    # lock losses bridged: far more of the trial is usable than sync's segments alone
    assert report["usable_fraction"] >= 0.85 > report["synced_segment_fraction"]
    truth = trial.truth.set_index("t_ns").loc[kin["t_ns"].to_numpy()]
    for acc, r2_min in (("udot_mps2", 0.93), ("vdot_mps2", 0.88), ("rdot_radps2", 0.98)):
        err = kin[acc].to_numpy() - truth[acc].to_numpy()
        assert 1 - np.mean(err**2) / np.var(truth[acc].to_numpy()) >= r2_min, acc
    for vel, sd in (("u_mps", "u_smooth_std_mps"), ("v_mps", "v_smooth_std_mps"), ("r_radps", "r_smooth_std_radps")):
        cover = np.mean(np.abs(kin[vel].to_numpy() - truth[vel].to_numpy()) <= 2 * kin[sd].to_numpy())
        assert 0.85 <= cover <= 0.995, (vel, cover)
    assert np.isnan(kin["u_meas_mps"]).any() and not np.isnan(kin["u_mps"]).any()  # bridged samples
    derived = derive(kin, vehicle)
    assert (derived["d_std_u_N"] > 0).all() and np.isfinite(derived["d_std_r_Nm"]).all()


def test_damping_sd_at_rest_is_the_mass_times_the_acceleration_sd() -> None:
    from pipeline.derive import damping_sd

    rng = np.random.default_rng(11)
    A = rng.uniform(-1, 1, (6, 6))
    M = A @ A.T + 6 * np.eye(6)
    nudot_sd = rng.uniform(0.01, 0.1, (5, 6))
    got = damping_sd(M, np.zeros((5, 6)), rng.uniform(0.01, 0.1, (5, 6)), nudot_sd)  # C(0) = 0, dC/dnu(0) = 0
    np.testing.assert_allclose(got, np.sqrt(nudot_sd**2 @ (M**2).T), rtol=1e-9)
    # in motion the velocity's SD adds through the Coriolis Jacobian: d_std grows
    nu = np.tile([0.8, 0.1, 0.0, 0.0, 0.0, 0.3], (5, 1))
    assert np.all(damping_sd(M, nu, np.full((5, 6), 0.05), nudot_sd) >= got - 1e-12)


def test_report_shows_noise_usable_fraction_and_the_band(realistic, tmp_path) -> None:
    from pipeline import layout
    from pipeline.config import Params
    from pipeline.estimation.differentiate import differentiate
    from pipeline.report.build import _estimation_section
    from pipeline.sync import synchronize
    from pipeline.tableio import write_json
    from tests.store.test_stages_features import signal_tables

    vehicle, trial = realistic
    params = Params()
    tables = signal_tables(trial, vehicle)
    kin, report = differentiate(synchronize(tables, vehicle, params.sync), vehicle, params.differentiate, tables)
    layout.kinematics_path(tmp_path, "t1").parent.mkdir(parents=True)
    kin.to_parquet(layout.kinematics_path(tmp_path, "t1"))
    write_json(report, layout.estimation_report_path(tmp_path, "t1"))
    metrics: dict = {}
    figs: dict = {}
    html = _estimation_section(tmp_path, ["t1"], metrics, figs)
    assert "dvl_x_mps" in html and "r_fog_radps" in html and "maximum likelihood" in html
    # the passes with the vehicle's model, the sensor errors found, and the excitation against the DVL
    assert "Smoother passes" in html and "(kept)" in html and "fitted damping" in html
    assert "Sensor errors estimated from the trial" in html and "r_fog_radps bias" in html
    assert "velocity sensor yaw misalignment" in html
    assert "actuator clock offset" in html and "actuator_clock_offset" in report
    assert "band the velocity sensor resolves" in html
    for dof in "uv":
        band = report["excitation"][dof]
        assert 0.05 < band["resolved_band_hz"] < 1.0 and 0.0 <= band["power_above_band"] < 0.5
    assert metrics["estimation"]["t1"]["usable_fraction"] == pytest.approx(report["usable_fraction"], abs=1e-6)
    assert figs["estimation_t1"][:8] == b"\x89PNG\r\n\x1a\n"


def test_median_interval_of_two_sources_is_their_merged_spacing() -> None:
    """Two 4-Hz sources of one DOF, a quarter-period apart and concatenated (not merged): the stamps' median
    interval, which sets the likelihood fit's grid stride, is that of the merged stream, 0.125 s; the concatenated
    order's differences would give 0.25 s."""
    from pipeline.estimation.smoother import _median_interval

    t = np.arange(0, 40) * 250_000_000
    a = Measurements(t, np.zeros(t.size), 1.0)
    b = Measurements(t + 125_000_000, np.zeros(t.size), 1.0)
    assert _median_interval(Measurements.concat(a, b)) == pytest.approx(0.125)
    assert _median_interval(a) == pytest.approx(0.25)
