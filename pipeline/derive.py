"""Forces from the kinematics table: thrust per thruster, generalized forces and the damping target.

``derive(kin, vehicle)`` is pure. It adds to the kinematics table (rows and columns kept):

- ``T_<thruster>_N``: thrust of each thruster (config order) from its input signal, by
  :func:`pipeline.physics.thrusts`: propeller speed (rpm; ``k n|n|`` or the interpolated thrust table), PWM (the
  table's PWM column) or a measured thrust (as it is);
- ``tau_*``: generalized forces tau = B T (allocation matrix B);
- ``Mnudot_*`` = M nu_dot, ``Cnu_*`` = C(nu) nu, ``g_*`` = g(eta) from roll and pitch;
- ``d_*`` = tau - M nu_dot - C(nu) nu - g(eta), the damping target.

Which nu: the accelerations come from smoothed data, so C(nu) nu uses the **smoothed** velocities
(``u_smooth_mps`` ...) as well: the terms of d then belong to the same filtered signal, and C(nu) nu, being
quadratic in nu, gets no noise-squared bias. The measured velocities stay in the table for the models.

Uncertainty: when the kinematics table carries the smoother's SDs (``u_smooth_std_mps`` ..., ``udot_std_mps2``
..., the ``kalman`` method), ``d_std_*`` is the first-order SD of d: var(d_i) = sum_j M_ij^2 var(nudot_j) +
sum_j (d(C(nu) nu)_i / d nu_j)^2 var(nu_j), the Jacobian by central differences, errors of different DOFs and of
nu and nudot taken as independent (tau and g as exact).

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
from pipeline.vocabulary import ACCELERATION, DOFS, SMOOTH, accel_std_column, force_columns, std_column

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
        sd = damping_sd(M, nu, kin[sd_cols[:6]].to_numpy(dtype=float), kin[sd_cols[6:]].to_numpy(dtype=float))
        for j, col in enumerate(force_columns("d_std")):
            new[col] = sd[:, j]
    clash = [c for c in new if c in out.columns]
    if clash:
        log.warning("kinematics table already has %s; overwritten", clash)
        out = out.drop(columns=clash)
    return pd.concat([out, pd.DataFrame(new, index=out.index)], axis=1)


def damping_sd(M: np.ndarray, nu: np.ndarray, nu_sd: np.ndarray, nudot_sd: np.ndarray, step: float = 1e-6
               ) -> np.ndarray:
    """First-order SD of d = tau - M nudot - C(nu) nu - g from the SDs of nu and nudot (see the module docstring)."""
    var = (nudot_sd**2) @ (M**2).T
    for j in range(nu.shape[1]):
        dn = np.zeros(nu.shape[1])
        dn[j] = step
        jac = (physics.coriolis_force(M, nu + dn) - physics.coriolis_force(M, nu - dn)) / (2 * step)
        var += jac**2 * nu_sd[:, j:j + 1] ** 2
    return np.sqrt(var)
