"""A velocity sensor's yaw misalignment, where the trial makes it identifiable.

A DVL mounted psi off its configured yaw reports, after the configured mount is undone, the body velocity turned
by -psi: (u, v) measured = R_z(-psi) (u, v) true, so a share psi of u leaks into v and the other way round. The
white-jerk smoother alone cannot tell that leak from motion (any v is as likely as any other), but with the
vehicle's model in the process equation (:mod:`pipeline.estimation.forced`) sway is predicted from the sway
thrust, and the leak shows as a misfit. The estimate is a profile likelihood: the measurements turned back by
each psi of a grid, smoothed with the final passes' inputs and process noises, their log-likelihoods summed over
u and v; a parabola through the grid gives psi and its SD (the curvature: the observed information). It is
identifiable when the parabola opens downwards, its vertex lies inside the grid and its SD is at most
``max_sd_deg``; otherwise the configured mount is kept and the report says why.

The rotation is exact for a mount turned in yaw alone; its roll and pitch parts stay as configured.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import numpy as np

from pipeline.estimation.forced import smooth_with_input
from pipeline.estimation.smoother import Measurements, Smoothed

log = logging.getLogger(__name__)

__all__ = ["Misalignment", "estimate_misalignment", "turned"]


@dataclass(frozen=True)
class Misalignment:
    """The yaw misalignment found (degrees, true mount - configured), its SD, and whether it is used."""

    estimate_deg: float | None
    sd_deg: float | None
    identifiable: bool
    reason: str | None = None

    def as_dict(self) -> dict:
        return asdict(self)


def turned(u: Measurements, v: Measurements, psi_rad: float) -> tuple[Measurements, Measurements]:
    """u and v measured at the same stamps, turned by +psi (undoing a mount psi off in yaw)."""
    c, s = np.cos(psi_rad), np.sin(psi_rad)
    return (Measurements(u.t_ns, c * u.y - s * v.y, u.var, u.order),
            Measurements(v.t_ns, s * u.y + c * v.y, v.var, v.order))


def estimate_misalignment(grid_ns: np.ndarray, u: Measurements, v: Measurements, fit_u: Smoothed, fit_v: Smoothed,
                          input_u: np.ndarray | None, input_v: np.ndarray | None, *, span_deg: float = 3.0,
                          points: int = 7, max_sd_deg: float = 0.1) -> Misalignment:
    """The profile likelihood of a yaw misalignment (see the module docstring). ``u``, ``v``: the velocity
    sensor's measurements in body axes at the same stamps; ``fit_u``, ``fit_v``: the smoother's chosen results
    (their kept measurements, process noises); ``input_u``, ``input_v``: the inputs they used (None: kinematic)."""
    if input_u is None and input_v is None:
        return Misalignment(None, None, False, "the vehicle's model was not taken for u or v: the smoother alone "
                                               "cannot tell a misalignment from motion")
    if u.t_ns.shape != v.t_ns.shape or not np.array_equal(u.t_ns, v.t_ns):
        return Misalignment(None, None, False, "u and v are not measured at the same stamps")
    both = fit_u.kept & fit_v.kept
    u, v = u.subset(both), v.subset(both)
    grid = np.linspace(-span_deg, span_deg, points)
    loglik = []
    for psi in np.radians(grid):
        tu, tv = turned(u, v, psi)
        ll = 0.0
        for meas, fit, a in ((tu, fit_u, input_u), (tv, fit_v, input_v)):
            ll += smooth_with_input(grid_ns, meas, a, q=fit.q, s=fit.s, gate=0).loglik
        loglik.append(ll)
    a2, a1, _ = np.polyfit(grid, np.asarray(loglik) - max(loglik), 2)
    if a2 >= 0:
        return Misalignment(None, None, False, "the likelihood has no maximum in yaw misalignment")
    estimate, sd = -a1 / (2 * a2), float(np.sqrt(-1.0 / (2 * a2)))
    if abs(estimate) > span_deg:
        return Misalignment(float(estimate), sd, False, f"the likelihood's maximum lies beyond ±{span_deg} deg")
    if sd > max_sd_deg:
        return Misalignment(float(estimate), sd, False,
                            f"SD {sd:.2g} deg above {max_sd_deg} deg: the trial's excitation does not pin it down")
    return Misalignment(float(estimate), sd, True)
