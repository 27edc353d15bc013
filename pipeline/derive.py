"""Forces from the kinematics table: thrust per thruster, generalized forces and the damping target.

``derive(kin, vehicle)`` is pure. It adds to the kinematics table (rows and columns kept):

- ``T_<thruster>_N``: thrust of each thruster (config order) from its input signal, by
  :func:`pipeline.physics.thrusts`: propeller speed (rpm; ``k n|n|`` or the interpolated thrust table), PWM (the
  table's PWM column) or a measured thrust (as it is);
- ``tau_*``: generalized forces tau = B T (allocation matrix B), plus the force of each control surface with a
  ``lift`` model (:func:`pipeline.physics.surface_forces`, from the smoothed velocities; not in tau's SD);
- ``Mnudot_*`` = M nu_dot, ``Cnu_*`` = C(nu) nu, ``g_*`` = g(eta) from roll and pitch;
- ``d_*`` = tau - M nu_dot - C(nu) nu - g(eta), the damping target.

Which nu: the accelerations come from smoothed data, so C(nu) nu uses the **smoothed** velocities
(``u_smooth_mps`` ...) as well: the terms of d then belong to the same filtered signal, and C(nu) nu, being
quadratic in nu, gets no noise-squared bias. The measured velocities stay in the table for the models.

Uncertainty: when the kinematics table carries the smoother's SDs (``u_smooth_std_mps`` ..., ``udot_std_mps2``
..., the ``kalman`` method), ``d_std_*`` is the first-order SD of d:

    var(d_i) = var(tau_i) + sum_j [M_ij^2 var(nudot_j) + J_ij^2 var(nu_j) + 2 M_ij J_ij cov(nu_j, nudot_j)],

J = d(C(nu) nu)/d nu by central differences (exact: C(nu) nu is quadratic), cov(nu_j, nudot_j) the smoother's
(``u_udot_cov_m2ps3`` ...; 0 for the grid methods and for velocities from positions).
var(tau_i) = sum_k B_ik^2 (dT_k/dn sigma_k)^2: sigma_k each actuator signal's white-noise (or quantization) SD,
estimated from the signal on the table's grid (:func:`pipeline.estimation.noise.estimate_noise`; the stage has no
native streams), dT/dn the secant of the thrust map over n +- sigma_k, thrusters independent.

Counted: the smoother's joint errors of nu and nudot per DOF; the actuator signals' noise and quantization, and
the part of a held (zero-order-hold) signal's staircase the noise estimate sees as noise. Not counted: errors of
different DOFs as correlated (the smoother runs per DOF); the covariance of tau and nudot that the model-aware
smoother creates by taking tau as its input (positive: d's SD errs wide);
a pure delay of an actuator signal (a counter stamps the mean of its window at the window's end, half a window
late), which the signal alone does not show: it is a clock offset, to be estimated and corrected, not widened;
errors of the thrust map, M and the attitude (g).

All vectors are 6-DOF. DOFs the vehicle does not measure (rates not configured, see
:mod:`pipeline.kinematics`) carry zeros in nu and nu_dot, so their terms reduce to what tau and g give;
models choose the DOFs they use. Columns are named ``<prefix>_<dof>_<N|Nm>``.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from pipeline import physics
from pipeline.config.vehicle import Vehicle, thrust_column
from pipeline.errors import SchemaError
from pipeline.estimation.noise import estimate_noise
from pipeline.vocabulary import ACCELERATION, DOFS, SMOOTH, accel_std_column, cov_column, force_columns, std_column

log = logging.getLogger(__name__)

TERMS = ("tau", "Mnudot", "Cnu", "g", "d")


def derived_columns(vehicle: Vehicle) -> list[str]:
    """The columns :func:`derive` adds, in order."""
    cols = [thrust_column(t.name) for t in vehicle.thrusters]
    for prefix in TERMS:
        cols += force_columns(prefix)
    return cols


def _need(kin: pd.DataFrame, columns: list[str], what: str) -> np.ndarray:
    missing = [c for c in columns if c not in kin.columns]
    if missing:
        raise SchemaError(f"{what}: column(s) {missing} missing from the kinematics table; "
                          f"found {list(kin.columns)}", field=missing[0])
    return kin[columns].to_numpy(dtype=float)


def derive(kin: pd.DataFrame, vehicle: Vehicle) -> pd.DataFrame:
    """The derived table: kinematics plus thrust, tau, M nu_dot, C(nu) nu, g(eta) and d."""
    speeds = np.empty((len(kin), len(vehicle.thrusters)))
    for i, thr in enumerate(vehicle.thrusters):
        if thr.input_signal not in kin.columns:
            raise SchemaError(f"thrusters[{i}] ({thr.name}).{thr.input_kind}_signal {thr.input_signal!r} is not a "
                              f"column of the kinematics table; found {list(kin.columns)}", field=thr.input_signal)
        speeds[:, i] = kin[thr.input_signal].to_numpy(dtype=float)
    nudot = _need(kin, ACCELERATION, "accelerations")
    nu = _need(kin, SMOOTH, "smoothed velocities")
    attitude = _need(kin, ["roll_rad", "pitch_rad"], "attitude for g(eta)")

    M = physics.mass_matrix(vehicle)
    T = physics.thrusts(vehicle, speeds)
    tau = T @ physics.allocation_matrix(vehicle).T
    lifting = [c for c in vehicle.control_surfaces if c.lift is not None]
    if lifting:  # rudders and fins with a lift model: their force is part of tau
        angles = np.column_stack([kin[c.angle_signal].to_numpy(dtype=float) if c.lift is not None
                                  else np.zeros(len(kin)) for c in vehicle.control_surfaces])
        tau = tau + physics.surface_forces(vehicle, nu, angles, T)
    m_nudot = nudot @ M.T
    c_nu = physics.coriolis_force(M, nu)
    g = physics.restoring_force(vehicle, attitude[:, 0], attitude[:, 1])
    d = physics.damping_target(M, tau, nudot, nu, g)

    out = kin.copy()
    new: dict[str, np.ndarray] = {thrust_column(t.name): T[:, i] for i, t in enumerate(vehicle.thrusters)}
    for prefix, values in zip(TERMS, (tau, m_nudot, c_nu, g, d), strict=True):
        for j, col in enumerate(force_columns(prefix)):
            new[col] = values[:, j]
    sd_cols = [std_column(d) for d in DOFS] + [accel_std_column(d) for d in DOFS]
    if all(c in kin.columns for c in sd_cols):
        cov_cols = [cov_column(d) for d in DOFS]
        cov = kin[cov_cols].to_numpy(dtype=float) if all(c in kin.columns for c in cov_cols) else None
        if cov is None:
            log.warning("kinematics table has SDs but no %s...: d's SD takes nu and nu_dot as independent",
                        cov_cols[0])
        t_s = (kin["t_ns"].to_numpy(dtype=np.int64) - int(kin["t_ns"].iloc[0])) / 1e9 if len(kin) else np.zeros(0)
        tau_var = thrust_variance(vehicle, speeds, t_s) @ (physics.allocation_matrix(vehicle).T ** 2)
        sd = damping_sd(M, nu, kin[sd_cols[:6]].to_numpy(dtype=float), kin[sd_cols[6:]].to_numpy(dtype=float),
                        cov, tau_var)
        for j, col in enumerate(force_columns("d_std")):
            new[col] = sd[:, j]
    clash = [c for c in new if c in out.columns]
    if clash:
        log.warning("kinematics table already has %s; overwritten", clash)
        out = out.drop(columns=clash)
    return pd.concat([out, pd.DataFrame(new, index=out.index)], axis=1)


def input_noise_sd(t_s: np.ndarray, x: np.ndarray, name: str) -> float:
    """The white-noise (quantization) SD of one actuator signal on the grid (:func:`estimate_noise`); 0, with a
    warning, where too few samples allow no estimate."""
    est = estimate_noise(t_s, x)
    if not np.isfinite(est.sd):
        log.warning("%s: too few samples (%d residuals) to estimate its noise; tau's SD takes it as exact",
                    name, est.samples)
        return 0.0
    return float(est.sd)


def thrust_variance(vehicle: Vehicle, inputs: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Variance of each thruster's thrust, (n, n_thrusters), from its input signal's noise (column i of
    ``inputs``, on the grid ``t_s``): (dT/dn sigma_n)^2, the slope the secant of the thrust map over
    n +- sigma_n (so that where T = k n|n| is flat, at n = 0, the error's second-order part remains)."""
    base = vehicle.resolve("")
    var = np.zeros_like(inputs, dtype=float)
    for i, thr in enumerate(vehicle.thrusters):
        sigma = input_noise_sd(t_s, inputs[:, i], thr.input_signal)
        if sigma > 0:
            n = inputs[:, i]
            slope = (physics.thrust_N(thr, n + sigma, base) - physics.thrust_N(thr, n - sigma, base)) / (2 * sigma)
            var[:, i] = (slope * sigma) ** 2
    return var


def damping_sd(M: np.ndarray, nu: np.ndarray, nu_sd: np.ndarray, nudot_sd: np.ndarray,
               cov: np.ndarray | None = None, tau_var: np.ndarray | None = None, step: float = 1e-6
               ) -> np.ndarray:
    """First-order SD of d = tau - M nudot - C(nu) nu - g (see the module docstring): ``cov`` (n, 6) the
    covariance of nu_j and nudot_j per DOF (None: 0), ``tau_var`` (n, 6) the variance of tau (None: 0)."""
    var = (nudot_sd**2) @ (M**2).T
    if tau_var is not None:
        var += tau_var
    for j in range(nu.shape[1]):
        dn = np.zeros(nu.shape[1])
        dn[j] = step
        jac = (physics.coriolis_force(M, nu + dn) - physics.coriolis_force(M, nu - dn)) / (2 * step)
        var += jac**2 * nu_sd[:, j:j + 1] ** 2
        if cov is not None:  # d_i = ... - M_ij nudot_j - (C nu)_i: the pair (nu_j, nudot_j) adds 2 M_ij J_ij cov_j
            var += 2.0 * M[:, j] * jac * cov[:, j:j + 1]
    return np.sqrt(np.maximum(var, 0.0))
