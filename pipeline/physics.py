"""Rigid-body physics of the vehicle: thrust, allocation, M, C(nu), g(eta) and the damping target.

Everything is vectorized over samples: velocity-like arrays are ``(n, 6)`` in Fossen's DOF order
:data:`pipeline.vocabulary.DOFS` = u v w p q r (body FRD axes, about the body origin CO), forces are ``(n, 6)`` in
N / N*m (columns: :func:`pipeline.vocabulary.force_columns`), propeller speeds are rpm. The equation of motion is

    M nu_dot + C(nu) nu + d(nu) + g(eta) = tau,        tau = B T,

so :func:`damping_target` returns ``d = tau - M nu_dot - C(nu) nu - g(eta)``.

Thrust tables: a CSV with a speed column (rpm) and a thrust column (any force unit of
:mod:`pipeline.units`, e.g. ``kgf``). Header names are compared after stripping whitespace. A table whose
speeds are all non-negative while its thrust takes both signs (the Blue Robotics T200 sheet: RPM unsigned,
reverse thrust negative) is read as *unsigned* speed: each row's speed takes the sign of its thrust. Rows
with equal speed are averaged. Speeds beyond the table are **clamped** to the end values (the propeller was
not measured there; extrapolating a fitted curve would invent thrust), with a logged warning.

A table is read only if it is a regular file of at most :data:`MAX_TABLE_BYTES` (a device such as ``/dev/zero``
or a FIFO would never end); every cell of the columns used must be a finite number (a row left wholly empty is
skipped), and the thrust must be monotonic in the speed (PWM), up to :data:`MONOTONIC_SLACK` of its range.
"""

from __future__ import annotations

import functools
import io
import logging
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.config.rigid_body import RigidBody, check_spd, rigid_body_mass, skew
from pipeline.config.vehicle import Thruster, Vehicle
from pipeline.errors import ConfigError
from pipeline.units import SOURCE_UNITS

if TYPE_CHECKING:
    import pandas as pd

log = logging.getLogger(__name__)


def added_mass_matrix(vehicle: Vehicle) -> np.ndarray:
    """The configured 6x6 added-mass matrix M_A, checked for shape and symmetry."""
    ma = np.asarray(vehicle.added_mass, dtype=float)
    if ma.shape != (6, 6):
        raise ConfigError(f"added_mass must be 6x6, found shape {ma.shape}", field="added_mass")
    if not np.all(np.isfinite(ma)):
        raise ConfigError("added_mass has non-finite entries", field="added_mass")
    if not np.allclose(ma, ma.T, rtol=1e-9, atol=1e-9 * max(1.0, float(np.abs(ma).max()))):
        raise ConfigError(f"added_mass must be symmetric; max |A - A^T| = {np.abs(ma - ma.T).max():.3g}",
                          field="added_mass")
    return ma


def mass_matrix(vehicle: Vehicle) -> np.ndarray:
    """M = M_RB + M_A, validated symmetric positive definite (ConfigError names the offending key)."""
    m_rb = rigid_body_mass(vehicle.rigid_body)
    m = m_rb + added_mass_matrix(vehicle)
    check_spd(m, "added_mass", "the mass matrix M = M_RB + M_A")
    return m


def _momenta(M: np.ndarray, nu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Linear and angular velocity (v1, v2) and the momenta a = M11 v1 + M12 v2, b = M21 v1 + M22 v2 of the
    symmetric part of M, per sample: the pieces C(nu) is built from."""
    M = np.asarray(M, dtype=float)
    ms = 0.5 * (M + M.T)
    nu = np.atleast_2d(np.asarray(nu, dtype=float))
    v1, v2 = nu[:, :3], nu[:, 3:]
    return v1, v2, v1 @ ms[:3, :3].T + v2 @ ms[:3, 3:].T, v1 @ ms[3:, :3].T + v2 @ ms[3:, 3:].T


def coriolis_matrix(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Coriolis-centripetal matrix C(nu) from M, Fossen's skew-symmetric form; nu (n, 6) -> (n, 6, 6).

    ``C = [[0, -S(M11 v1 + M12 v2)], [-S(M11 v1 + M12 v2), -S(M21 v1 + M22 v2)]]`` with the symmetric part
    of M, so that ``nu . C(nu) nu = 0`` for every nu.
    """
    v1, v2, a, b = _momenta(M, nu)
    out = np.zeros((nu.shape[0], 6, 6))
    sa = skew(a)
    out[:, :3, 3:] = -sa
    out[:, 3:, :3] = -sa
    out[:, 3:, 3:] = -skew(b)
    return out


def coriolis_force(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C(nu) nu, (n, 6), without building the (n, 6, 6) stack."""
    v1, v2, a, b = _momenta(M, nu)
    # -S(a) v2 = -a x v2 = v2 x a ; -S(a) v1 - S(b) v2 = v1 x a + v2 x b
    return np.hstack([np.cross(v2, a), np.cross(v1, a) + np.cross(v2, b)])


def weight_buoyancy_N(rb: RigidBody) -> tuple[float, float]:
    """(W, B) in N: W = m g; B from the config or equal to W (neutral)."""
    w = rb.mass_kg * rb.gravity_mps2
    return w, (w if rb.buoyancy_N is None else float(rb.buoyancy_N))


def restoring_force(vehicle: Vehicle, roll_rad: np.ndarray, pitch_rad: np.ndarray) -> np.ndarray:
    """Restoring forces g(eta), (n, 6), for a submerged vehicle (Fossen 2011, eq. 4.6)."""
    rb = vehicle.rigid_body
    w, b = weight_buoyancy_N(rb)
    xg, yg, zg = rb.cg_m
    xb, yb, zb = rb.cb_m
    phi = np.atleast_1d(np.asarray(roll_rad, dtype=float))
    theta = np.atleast_1d(np.asarray(pitch_rad, dtype=float))
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    out = np.empty((phi.shape[0], 6))
    out[:, 0] = (w - b) * sth
    out[:, 1] = -(w - b) * cth * sphi
    out[:, 2] = -(w - b) * cth * cphi
    out[:, 3] = -(yg * w - yb * b) * cth * cphi + (zg * w - zb * b) * cth * sphi
    out[:, 4] = (zg * w - zb * b) * sth + (xg * w - xb * b) * cth * cphi
    out[:, 5] = -(xg * w - xb * b) * cth * sphi - (yg * w - yb * b) * sth
    return out


def allocation_matrix(vehicle: Vehicle) -> np.ndarray:
    """Thrust allocation B, (6, n_thrusters): column i is [d_i; r_i x d_i] with d_i normalized."""
    cols = []
    for i, thr in enumerate(vehicle.thrusters):
        d = np.asarray(thr.direction, dtype=float)
        norm = float(np.linalg.norm(d))
        if not np.isfinite(norm) or norm < 1e-12:
            raise ConfigError(f"thruster {thr.name!r} has a zero (or non-finite) direction {thr.direction}",
                              field=f"thrusters.{i}.direction")
        d = d / norm
        r = np.asarray(thr.position_m, dtype=float)
        cols.append(np.concatenate([d, np.cross(r, d)]))
    return np.stack(cols, axis=1)


#: Largest thrust table read (bytes): a measured sheet is a few hundred rows (the T200's 10-20 V sheet: 14 kB).
MAX_TABLE_BYTES = 16 << 20

#: How far the thrust may go against the table's direction between neighbouring speeds, as a share of the
#: thrust's range: measurement noise in a dead band (the T200 sheet: 0.2 %); a mistyped row is far beyond.
MONOTONIC_SLACK = 0.05


def _table_text(path: str) -> str:
    """The table's text: a regular file of at most MAX_TABLE_BYTES, as UTF-8 (stat first: opening a FIFO blocks)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise ConfigError("thrust table not found", file=path, field="thrust.table") from None
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError("thrust table is not a regular file (a directory, device or FIFO); give a CSV file",
                          file=path, field="thrust.table")
    with open(path, "rb") as handle:
        data = handle.read(MAX_TABLE_BYTES + 1)  # the size stat gave may have grown since
    if len(data) > MAX_TABLE_BYTES:
        raise ConfigError(f"thrust table is larger than {MAX_TABLE_BYTES >> 20} MiB; a measured table is a few "
                          "hundred rows", file=path, field="thrust.table")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ConfigError(f"thrust table is not UTF-8 text: {err}", file=path, field="thrust.table") from None


def _read_table(path: str) -> pd.DataFrame:
    import pandas as pd  # only for a thrust table: the config validation on every command's path does not need it

    text = _table_text(path)
    try:
        frame = pd.read_csv(io.StringIO(text), sep=None, engine="python")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as err:
        raise ConfigError(f"thrust table cannot be parsed: {err}", file=path, field="thrust.table") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame


def _numeric(frame: pd.DataFrame, column: str, key: str, path: str) -> np.ndarray:
    if column.strip() not in frame.columns:
        raise ConfigError(f"column {column!r} not in thrust table; available: {list(frame.columns)}", file=path,
                          field=key)
    import pandas as pd

    return pd.to_numeric(frame[column.strip()], errors="coerce").to_numpy(dtype=float)


def _check_finite(columns: dict[str, np.ndarray], path: str) -> np.ndarray:
    """Rows to use: those with every used cell empty are skipped; any other non-finite cell is refused by line."""
    stacked = np.column_stack(list(columns.values()))
    finite = np.isfinite(stacked)
    empty = np.isnan(stacked).all(axis=1)
    bad = ~finite.all(axis=1) & ~empty
    if bad.any():
        rows = np.flatnonzero(bad)
        col = list(columns)[int(np.flatnonzero(~finite[rows[0]])[0])]
        raise ConfigError(f"thrust table has {rows.size} row(s) with a cell that is empty, not a number, NaN or "
                          f"infinite in the columns used (first: data row {int(rows[0]) + 1}, column {col!r}); every "
                          "speed, PWM, thrust and voltage must be a finite number", file=path, field="thrust.table")
    return ~empty


def _check_monotonic(x: np.ndarray, thrust: np.ndarray, path: str, by: str) -> None:
    """Thrust monotonic in x (rising or falling), up to MONOTONIC_SLACK of its range."""
    steps = np.diff(thrust)
    against = -steps if thrust[-1] >= thrust[0] else steps
    worst = int(np.argmax(against))
    span = float(thrust.max() - thrust.min())
    if against[worst] > MONOTONIC_SLACK * span:
        what = "speed (rpm)" if by == "speed" else "PWM"
        raise ConfigError(f"thrust is not monotonic in the {what}: from {x[worst]:g} to {x[worst + 1]:g} it goes "
                          f"from {thrust[worst]:g} N to {thrust[worst + 1]:g} N, against the table's direction by "
                          f"more than {MONOTONIC_SLACK:.0%} of its range ({span:g} N); a mistyped row?", file=path,
                          field="thrust.table")


def _curve(x: np.ndarray, thrust: np.ndarray, unsigned_speed: bool) -> tuple[np.ndarray, np.ndarray]:
    if unsigned_speed and x.min() >= 0 and thrust.min() < 0:
        x = x * np.sign(thrust)  # unsigned speed column: the thrust sign gives the direction
    uniq, inverse = np.unique(x, return_inverse=True)
    return uniq, np.bincount(inverse, weights=thrust) / np.bincount(inverse)


@functools.lru_cache(maxsize=32)
def _load_table(path: str, speed_column: str, thrust_column: str, unit: str, by: str = "speed",
                voltage_column: str | None = None, voltage_V: float | None = None,
                x_factor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(x, thrust N) sorted by x, duplicates averaged; x is the signed speed in rpm (``by="speed"``) or the PWM
    pulse width times ``x_factor`` (``by="pwm"``). At ``voltage_V``: the rows of that voltage, or the thrust
    interpolated between the two measured voltages around it. Cached per file and columns."""
    frame = _read_table(path)
    key = "thrust.table_speed_column" if by == "speed" else "thrust.table_pwm_column"
    x_all = _numeric(frame, speed_column, key, path) * x_factor
    thrust_all = _numeric(frame, thrust_column, "thrust.table_thrust_column", path)
    unit_def = SOURCE_UNITS.get(unit)
    if unit_def is None or unit_def.dimension != "force":
        known = sorted(k for k, v in SOURCE_UNITS.items() if v.dimension == "force")
        raise ConfigError(f"table_thrust_unit {unit!r} is not a force unit; known: {known}", file=path,
                          field="thrust.table_thrust_unit")
    thrust_all = thrust_all * unit_def.factor + unit_def.offset
    used = {speed_column: x_all, thrust_column: thrust_all}
    if voltage_column is not None:
        used[voltage_column] = _numeric(frame, voltage_column, "thrust.table_voltage_column", path)
    rows = _check_finite(used, path)
    x_all, thrust_all = x_all[rows], thrust_all[rows]
    if voltage_column is None:
        curves = [(1.0, _curve(x_all, thrust_all, by == "speed"))]
    else:
        volts = used[voltage_column][rows]
        levels = np.unique(volts[np.isfinite(volts)])
        near = levels[np.abs(levels - voltage_V) <= 0.05]
        if near.size:
            chosen, weights = [near[0]], [1.0]
        else:
            below, above = levels[levels < voltage_V], levels[levels > voltage_V]
            if not below.size or not above.size:
                raise ConfigError(f"voltage_V {voltage_V:g} is outside the table's voltages {levels.tolist()}",
                                  file=path, field="thrust.voltage_V")
            lo, hi = below.max(), above.min()
            chosen, weights = [lo, hi], [(hi - voltage_V) / (hi - lo), (voltage_V - lo) / (hi - lo)]
        curves = [(w, _curve(x_all[np.abs(volts - v) <= 0.05], thrust_all[np.abs(volts - v) <= 0.05], by == "speed"))
                  for v, w in zip(chosen, weights, strict=True)]
    x = np.unique(np.concatenate([c[1][0] for c in curves]))
    thrust = sum(w * np.interp(x, cx, ct) for w, (cx, ct) in curves)
    if x.size < 2:
        raise ConfigError("thrust table needs at least two numeric rows", file=path, field="thrust.table")
    thrust = np.asarray(thrust, dtype=float)
    _check_monotonic(x, thrust, path, by)
    x.setflags(write=False)
    thrust.setflags(write=False)
    return x, thrust


_PWM_TO_S = {"us": 1e-6, "ms": 1e-3, "s": 1.0}


def thrust_table(thruster: Thruster, base_dir: str | Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The thruster's measured table as (signed speed rpm, or PWM pulse width s; thrust N), sorted; see the module
    notes."""
    curve = thruster.thrust
    if curve is None or curve.table is None:
        raise ConfigError(f"thruster {thruster.name!r} has no thrust table", field="thrust.table")
    path = Path(curve.table)
    if base_dir is not None:
        path = Path(base_dir) / path
    assert curve.table_thrust_column is not None
    by_pwm = thruster.input_kind == "pwm"
    column = curve.table_pwm_column if by_pwm else curve.table_speed_column
    assert column is not None
    return _load_table(str(path.resolve()), column, curve.table_thrust_column, curve.table_thrust_unit,
                       "pwm" if by_pwm else "speed", curve.table_voltage_column, curve.voltage_V,
                       _PWM_TO_S[curve.table_pwm_unit] if by_pwm else 1.0)


def thrust_N(thruster: Thruster, n_rpm: np.ndarray, base_dir: str | Path | None = None) -> np.ndarray:
    """Thrust in N of one thruster from its input signal ``n_rpm`` (any shape): propeller speed in rpm, PWM pulse
    width in s, or a measured thrust in N (returned as it is), by the thruster's kind.

    ``k_fwd n|n|`` for n >= 0 and ``k_bwd n|n|`` for n < 0 (k_bwd defaults to k_fwd); or linear
    interpolation of the measured table (``base_dir``: directory the table path is relative to), clamped
    to the table's end values beyond its speed (PWM) range (logged as a warning).
    """
    n = np.asarray(n_rpm, dtype=float)
    if thruster.input_kind == "thrust":
        return n.copy()
    curve = thruster.thrust
    assert curve is not None
    if curve.table is None:
        k_fwd = float(curve.k_fwd_N_per_rpm2)  # type: ignore[arg-type]
        k_bwd = k_fwd if curve.k_bwd_N_per_rpm2 is None else float(curve.k_bwd_N_per_rpm2)
        return np.where(n >= 0, k_fwd, k_bwd) * n * np.abs(n)
    speed, thrust = thrust_table(thruster, base_dir)
    outside = (n < speed[0]) | (n > speed[-1])
    if np.any(outside):
        log.warning("thruster %s: %d of %d inputs outside the thrust table [%g, %g]; thrust clamped",
                    thruster.name, int(outside.sum()), n.size, speed[0], speed[-1])
    return np.interp(n, speed, thrust)


def thrusts(vehicle: Vehicle, speeds_rpm: np.ndarray) -> np.ndarray:
    """Per-thruster thrust in N, (n, n_thrusters), columns in config thruster order; column i of ``speeds_rpm``
    holds thruster i's input signal (speed rpm, PWM s or thrust N: :attr:`Thruster.input_signal`)."""
    speeds = np.atleast_2d(np.asarray(speeds_rpm, dtype=float))
    if speeds.shape[1] != len(vehicle.thrusters):
        raise ValueError(f"speeds_rpm has {speeds.shape[1]} columns, the vehicle {len(vehicle.thrusters)} thrusters")
    base = vehicle.resolve("")
    return np.stack([thrust_N(thr, speeds[:, i], base) for i, thr in enumerate(vehicle.thrusters)], axis=1)


def generalized_forces(vehicle: Vehicle, speeds_rpm: np.ndarray) -> np.ndarray:
    """tau = B T, (n, 6)."""
    return thrusts(vehicle, speeds_rpm) @ allocation_matrix(vehicle).T


def surface_forces(vehicle: Vehicle, nu: np.ndarray, angles_rad: np.ndarray, thrusts_N: np.ndarray) -> np.ndarray:
    """The generalized forces (n, 6) of the control surfaces that have a ``lift`` model; zero for the others.

    Per surface at r = ``position_m``: the inflow along x, u_R = u + q z - r y, with U_R^2 = u_R^2 (plus
    8 T / (rho pi D^2) of the thrust T of the thruster it sits ``behind``, when T > 0: momentum theory's far-wake
    slipstream); the cross-flow along its axis, w_c = v + r x - p z (axis y) or w + p y - q x (axis z); the angle
    of attack alpha = delta - atan2(w_c, U_R) (the cross-flow turns the inflow against a positive deflection); the
    lift L = 1/2 rho A C_La alpha U_R^2 along the axis, and its moment r x L. Linear in alpha (no stall): keep the
    angles within the lift slope's range. ``angles_rad`` (n, surfaces) and ``thrusts_N`` (n, thrusters) in config
    order (Fossen 2011, *Handbook of Marine Craft Hydrodynamics and Motion Control*, §9.5, rudder forces)."""
    nu = np.atleast_2d(np.asarray(nu, dtype=float))
    out = np.zeros((nu.shape[0], 6))
    u, v, w, p, q, r = nu.T
    names = [t.name for t in vehicle.thrusters]
    for i, surface in enumerate(vehicle.control_surfaces):
        lift = surface.lift
        if lift is None:
            continue
        x, y, z = lift.position_m
        u_r = u + q * z - r * y
        speed2 = u_r * u_r
        if lift.behind is not None:
            thrust = np.maximum(np.asarray(thrusts_N, dtype=float)[:, names.index(lift.behind)], 0.0)
            speed2 = speed2 + 8.0 * thrust / (lift.density_kg_m3 * np.pi * float(lift.slipstream_diameter_m) ** 2)
        cross = v + r * x - p * z if lift.axis == "y" else w + p * y - q * x
        alpha = np.asarray(angles_rad, dtype=float)[:, i] - np.arctan2(cross, np.sqrt(speed2))
        force = 0.5 * lift.density_kg_m3 * lift.area_m2 * lift.lift_slope_per_rad * alpha * speed2
        axis = np.array([0.0, 1.0, 0.0]) if lift.axis == "y" else np.array([0.0, 0.0, 1.0])
        out[:, :3] += force[:, None] * axis
        out[:, 3:] += force[:, None] * np.cross([x, y, z], axis)
    return out


def damping_target(M: np.ndarray, tau: np.ndarray, nudot: np.ndarray, nu: np.ndarray, g: np.ndarray) -> np.ndarray:
    """d = tau - M nu_dot - C(nu) nu - g(eta), (n, 6)."""
    M = np.asarray(M, dtype=float)
    nudot = np.atleast_2d(np.asarray(nudot, dtype=float))
    return np.atleast_2d(tau) - nudot @ M.T - coriolis_force(M, nu) - np.atleast_2d(g)
