"""The differentiate stage's pure function: a synced table (+ the trial's native streams) -> the kinematics table
and the estimation report.

:func:`differentiate` picks the method ``params.method`` names; every method takes the same arguments and returns
the same pair (the contract: ``docs/contracts.md``):

- ``kalman`` (the default): :func:`pipeline.estimation.kalman.estimate_motion`, a Kalman/RTS smoother over every
  velocity and rate sensor at its own stamps, with SDs;
- ``gaussian``, ``savgol``: :func:`pipeline.estimation.grid.filter_motion`, filters of the synced grid
  (:mod:`pipeline.estimation.gaussian`, :mod:`pipeline.estimation.savgol`).

Then, where ``notch_hz`` or ``max_hz`` is set, :func:`pipeline.estimation.spectral.band_limit` filters the
velocities and accelerations per segment (zero-phase), and the report's ``band_limit`` says what was applied;
otherwise, by default (``disturbances: remove``), :func:`pipeline.estimation.spectral.remove_disturbances` removes
the narrow-band disturbances the spectral check finds in an acceleration, and the report's ``disturbances`` names
each (frequency, share, what was applied).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import pandas as pd
import pyarrow as pa
from threadpoolctl import threadpool_limits

from pipeline.config.params import DifferentiateParams
from pipeline.config.vehicle import Vehicle

__all__ = ["METHODS", "differentiate", "kinematics", "method_function"]

#: The values of ``params.method``.
METHODS = ("kalman", "gaussian", "savgol")


def method_function(method: str) -> Callable[..., tuple[pd.DataFrame, dict[str, Any]]]:
    """The function that estimates the motion by ``method``: (synced, vehicle, params, streams) -> (table, report).
    Imported when asked for, so that a run imports only its method's modules (the grid filters' scipy.ndimage and
    scipy.signal cost more to import than the default smoother needs; docs/benchmarks.md)."""
    if method == "kalman":
        from pipeline.estimation.kalman import estimate_motion
        return estimate_motion
    if method in ("gaussian", "savgol"):
        from pipeline.estimation.grid import filter_motion
        return filter_motion
    raise ValueError(f"unknown differentiate method {method!r}; expected one of {list(METHODS)}")


def differentiate(synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams,
                  streams: Mapping[str, pd.DataFrame | pa.Table] | None = None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The kinematics table of the contract and the stage's report (noise per signal, the smoother or the filter
    widths, how much of the trial is usable). ``streams``: the trial's native streams (stem -> table), for the
    smoother and ``auto`` widths; without them the synced grid's samples stand in."""
    with threadpool_limits(1, user_api="blas"):  # banded solves and 3x3 blocks: BLAS threads only spin
        table, report = method_function(params.method)(synced, vehicle, params, streams)
    if params.notch_hz or params.max_hz is not None:  # the user's band limit, after any method, on the grid
        from pipeline.estimation.spectral import band_limit
        table, report["band_limit"] = band_limit(table, params)
    elif params.disturbances == "remove":  # what no actuator explains, found and removed per DOF
        from pipeline.estimation.spectral import remove_disturbances
        actuators = vehicle.actuator_signals() if vehicle is not None else []
        table, report["disturbances"] = remove_disturbances(table, params, actuators)
    return table, report


def kinematics(synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams,
               streams: Mapping[str, pd.DataFrame | pa.Table] | None = None) -> pd.DataFrame:
    """The kinematics table alone (:func:`differentiate` without the report)."""
    return differentiate(synced, vehicle, params, streams)[0]
