"""A velocity sensor's yaw misalignment, where the trial makes it identifiable.

A DVL mounted psi off its configured yaw reports, after the configured mount is undone, the body velocity turned
by -psi: (u, v) measured = R_z(-psi) (u, v) true, so a share psi of u leaks into v and the other way round. The
white-jerk smoother alone cannot tell that leak from motion (any v is as likely as any other), but with the
vehicle's model in the process equation (:mod:`pipeline.estimation.forced`) sway is predicted from the sway
thrust, and the leak shows as a misfit. The estimate is a profile likelihood: the measurements turned back by
each psi of a grid, smoothed with the final passes' inputs and process noises, their log-likelihoods summed over
u and v; a parabola through the grid gives psi and its SD (the curvature: the observed information). The trial
alone pins it down (``identifiable``) when the parabola opens downwards, its vertex lies inside the grid and its
SD is at most ``max_sd_deg``. Either way the estimate is combined with the prior on the configured mount
(``differentiate.mount_yaw_sd_deg``; Gaussian, precisions add): the posterior is undone where it lies further
from the configured mount than its own SD, and what remains of the mount's error widens u's and v's bands.

The rotation is exact for a mount turned in yaw alone; its roll and pitch parts stay as configured.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, replace

import numpy as np

from pipeline.estimation.forced import smooth_with_input
from pipeline.estimation.smoother import Measurements, Smoothed

log = logging.getLogger(__name__)

__all__ = ["Misalignment", "estimate_misalignment", "turned", "widen_for_misalignment", "zero_mean_posterior"]


@dataclass(frozen=True)
class Misalignment:
    """The yaw misalignment (degrees, true mount - configured): the trial's own estimate and SD (the profile
    likelihood; None where there is none), the trial alone pins it down (``identifiable``), the estimate combined
    with the prior on the configured mount (``posterior_deg``, ``posterior_sd_deg``), and whether that was undone
    (``applied``: the posterior is further from the configured mount than its own SD)."""

    estimate_deg: float | None
    sd_deg: float | None
    identifiable: bool
    reason: str | None = None
    posterior_deg: float = 0.0
    posterior_sd_deg: float = 0.0
    applied: bool = False

    def as_dict(self) -> dict:
        return asdict(self)

    def with_prior(self, prior_sd_deg: float) -> Misalignment:
        """Combined with a zero-mean prior of SD ``prior_sd_deg`` on the configured mount (Gaussian: precisions
        add); without a likelihood the posterior is the prior."""
        if prior_sd_deg <= 0:
            return replace(self, posterior_deg=0.0, posterior_sd_deg=0.0, applied=False)
        if self.estimate_deg is None or self.sd_deg is None:
            return replace(self, posterior_deg=0.0, posterior_sd_deg=prior_sd_deg, applied=False)
        mean, sd = zero_mean_posterior(self.estimate_deg, self.sd_deg, prior_sd_deg)
        return replace(self, posterior_deg=mean, posterior_sd_deg=sd, applied=bool(abs(mean) > sd))


def zero_mean_posterior(estimate: float, sd: float, prior_sd: float) -> tuple[float, float]:
    """Mean and SD of a Gaussian estimate ``estimate`` ± ``sd`` combined with a zero-mean prior of SD ``prior_sd``
    (precisions add): a trial's own estimate of a sensor error against its configured value."""
    weight = prior_sd**2 / (prior_sd**2 + sd**2)
    return float(weight * estimate), float(np.sqrt(weight) * sd)


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
    if abs(estimate) > span_deg:  # the parabola's vertex outside the grid: the likelihood says little
        return Misalignment(None, None, False, f"the likelihood's maximum lies beyond ±{span_deg} deg")
    if sd > max_sd_deg:
        return Misalignment(float(estimate), sd, False,
                            f"SD {sd:.2g} deg above {max_sd_deg} deg: the trial's excitation does not pin it down")
    return Misalignment(float(estimate), sd, True)


def widen_for_misalignment(u: Smoothed, v: Smoothed, found: Misalignment) -> None:
    """Add the mount's remaining yaw error to u's and v's SDs (velocity and acceleration).

    A mount psi off leaks -psi v into u and psi u into v, and their derivatives likewise: errors that follow the
    motion, not white noise, so the smoother's own SDs do not hold them. What remains: the posterior's SD where
    it was undone, else its RMS distance from the configured mount, sqrt(mean^2 + SD^2). Nothing is added where
    the trial gave no likelihood (the model was not taken: the smoother's SDs are as before).
    """
    if found.estimate_deg is None or u.x_sd is None or v.x_sd is None:
        return
    left = found.posterior_sd_deg if found.applied else float(np.hypot(found.posterior_deg, found.posterior_sd_deg))
    rms = np.radians(left)
    u_x, v_x, u_xdot, v_xdot = u.x.copy(), v.x.copy(), u.xdot.copy(), v.xdot.copy()
    u.x_sd = np.sqrt(u.x_sd**2 + (rms * v_x) ** 2)
    v.x_sd = np.sqrt(v.x_sd**2 + (rms * u_x) ** 2)
    u.xdot_sd = np.sqrt(u.xdot_sd**2 + (rms * v_xdot) ** 2)
    v.xdot_sd = np.sqrt(v.xdot_sd**2 + (rms * u_xdot) ** 2)
