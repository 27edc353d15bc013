"""The feature store's vocabulary: the degrees of freedom and the name of every per-DOF column, defined once.

Every module that reads or writes a per-DOF column builds its name here (``velocity_column("u")`` ->
``u_mps``), never by string surgery on another name. The unit suffix follows :mod:`pipeline.units`.
"""

from __future__ import annotations

#: Body-frame degrees of freedom, Fossen's order: surge, sway, heave, roll, pitch, yaw.
DOFS = ("u", "v", "w", "p", "q", "r")

#: Unit suffix of each DOF's velocity, acceleration and generalized force.
VEL_UNIT = {"u": "mps", "v": "mps", "w": "mps", "p": "radps", "q": "radps", "r": "radps"}
ACC_UNIT = {"u": "mps2", "v": "mps2", "w": "mps2", "p": "radps2", "q": "radps2", "r": "radps2"}
FORCE_UNIT = {"u": "N", "v": "N", "w": "N", "p": "Nm", "q": "Nm", "r": "Nm"}
FORCE_UNITS = tuple(FORCE_UNIT[d] for d in DOFS)
#: ... and of the covariance of a DOF's velocity and acceleration (velocity unit x acceleration unit).
COV_UNIT = {"u": "m2ps3", "v": "m2ps3", "w": "m2ps3", "p": "rad2ps3", "q": "rad2ps3", "r": "rad2ps3"}

#: Attitude columns on the grid (Z-Y-X Euler angles of body FRD in NED).
ATTITUDE = ["roll_rad", "pitch_rad", "yaw_rad"]


def velocity_column(dof: str) -> str:
    """The body velocity: ``u`` -> ``u_mps``, ``r`` -> ``r_radps``."""
    return f"{dof}_{VEL_UNIT[dof]}"


def smooth_column(dof: str) -> str:
    """The smoothed body velocity: ``u_smooth_mps``."""
    return f"{dof}_smooth_{VEL_UNIT[dof]}"


def acceleration_column(dof: str) -> str:
    """The body acceleration (the models' target): ``u`` -> ``udot_mps2``, ``r`` -> ``rdot_radps2``."""
    return f"{dof}dot_{ACC_UNIT[dof]}"


def std_column(dof: str) -> str:
    """SD of the smoothed velocity: ``u_smooth_std_mps``."""
    return f"{dof}_smooth_std_{VEL_UNIT[dof]}"


def accel_std_column(dof: str) -> str:
    """SD of the estimated acceleration: ``udot_std_mps2``."""
    return f"{dof}dot_std_{ACC_UNIT[dof]}"


def cov_column(dof: str) -> str:
    """Covariance of the smoothed velocity and the acceleration of the same DOF: ``u_udot_cov_m2ps3``."""
    return f"{dof}_{dof}dot_cov_{COV_UNIT[dof]}"


def meas_column(dof: str) -> str:
    """The measured velocity on the grid as sync resampled it: ``u_meas_mps``."""
    return f"{dof}_meas_{VEL_UNIT[dof]}"


def force_column(dof: str, prefix: str = "tau") -> str:
    """A generalized-force component: ``("u", "tau")`` -> ``tau_u_N``, ``("r", "d")`` -> ``d_r_Nm``."""
    return f"{prefix}_{dof}_{FORCE_UNIT[dof]}"


def force_columns(prefix: str = "tau") -> list[str]:
    """Column names of a generalized-force 6-vector: ``tau`` -> tau_u_N ... tau_r_Nm."""
    return [force_column(d, prefix) for d in DOFS]


VELOCITY = [velocity_column(d) for d in DOFS]
SMOOTH = [smooth_column(d) for d in DOFS]
ACCELERATION = [acceleration_column(d) for d in DOFS]
VELOCITY_COLUMNS = {d: velocity_column(d) for d in DOFS}
TAU_COLUMNS = {d: force_column(d, "tau") for d in DOFS}
DAMPING_COLUMNS = {d: force_column(d, "d") for d in DOFS}
#: The smoother's SDs the coupled study weights its explicit models with (u, v, r and their derivatives).
NOISE_STD_COLUMNS = (*(std_column(d) for d in ("u", "v", "r")), *(accel_std_column(d) for d in ("u", "v", "r")))
