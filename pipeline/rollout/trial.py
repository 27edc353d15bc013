"""The simulate stage's pure function: one test trial's free runs, horizon errors and DVL-outage bridging for every
fitted model, from the trial's table and the loaded models (no files; ``stages/simulate.py`` reads and writes).

Each decoupled model set ``{dof: estimator}`` becomes ``M nudot = tau - C(nu) nu - d(nu)`` with M and C from
:mod:`pipeline.physics` and tau from the measured thruster speeds (minus restoring forces when roll and pitch are
in the store); each coupled model ``(estimator, extra input columns)`` is rolled out as ``nudot = F(nu, inputs)``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from pipeline import physics
from pipeline.config import Params, Vehicle
from pipeline.rollout.bridging import bridge_outages
from pipeline.rollout.dynamics import CoupledDynamics, DecoupledDynamics
from pipeline.rollout.runs import FreeRun, run_models
from pipeline.rollout.tables import band_tables, damping_tables, table_range
from pipeline.vocabulary import DOFS, TAU_COLUMNS, VELOCITY_COLUMNS

log = logging.getLogger(__name__)


@dataclass
class TrialRollout:
    """What :func:`rollout_trial` computed: one :class:`FreeRun` per model (in the models' order), their horizon
    errors ``{model: {horizon: ...}}`` and the bridging rows (None when the trial cannot be bridged)."""

    t_ns: np.ndarray
    columns: list[str]
    runs: list[FreeRun]
    horizons: dict[str, Any]
    bridging: list[dict[str, Any]] | None

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"free_run": [r.summary() for r in self.runs], "horizons": self.horizons}
        if self.bridging is not None:
            out["bridging"] = self.bridging
        return out


def part_progress(progress: Callable[..., Any] | None, label: str) -> Callable[..., Any] | None:
    """A progress callback for one part of the work: the part's own done/total, ``label`` first in desc."""
    if progress is None:
        return None
    return lambda done, total=None, desc=None: progress(done, total, f"{label} {desc or ''}".rstrip())


def trial_inputs(frame: pd.DataFrame, vehicle: Vehicle, dofs: list[str]) -> np.ndarray:
    """Generalized forces of the simulated DOFs from the measured thruster speeds, minus restoring forces."""
    speeds = frame[[t.input_signal for t in vehicle.thrusters]].to_numpy(float)  # speed, PWM or thrust
    tau = physics.generalized_forces(vehicle, speeds)
    if {"roll_rad", "pitch_rad"} <= set(frame.columns):
        tau = tau - physics.restoring_force(vehicle, frame["roll_rad"].to_numpy(float),
                                            frame["pitch_rad"].to_numpy(float))
    return tau[:, [DOFS.index(d) for d in dofs]]


def rollout_trial(frame: pd.DataFrame, vehicle: Vehicle, params: Params, decoupled: Mapping[str, Mapping[str, Any]],
                  coupled: Mapping[str, tuple[Any, list[str]]], progress: Callable[..., Any] | None = None
                  ) -> TrialRollout:
    """Free runs, horizon errors and (with u, v and yaw in the store) bridging of the models ``decoupled``
    (``{model: {dof: estimator}}``) and ``coupled`` (``{name: (estimator, extra input columns)}``) on one trial."""
    p, dofs = params.simulate, list(params.decoupled.dofs)
    t_ns = frame["t_ns"].to_numpy(np.int64)
    seg = frame["segment"].to_numpy(int) if "segment" in frame else None
    nu = frame[[VELOCITY_COLUMNS[d] for d in dofs]].to_numpy(float)
    tau = trial_inputs(frame, vehicle, dofs)
    M = physics.mass_matrix(vehicle)
    ranges = {d: table_range(nu[:, j]) for j, d in enumerate(dofs)}
    dynamics: dict[str, tuple[Any, np.ndarray]] = {}
    bands: dict[str, Any] = {}
    for name, models in decoupled.items():
        dynamics[name] = (DecoupledDynamics(M, dofs, damping_tables(models, ranges), physics.coriolis_force), tau)
        if p.band_samples > 0 and all(hasattr(m, "sample_functions") for m in models.values()):
            bands[name] = DecoupledDynamics(M, dofs, band_tables(models, ranges, p.band_samples, p.seed),
                                            physics.coriolis_force)
    for name, (est, extra) in coupled.items():
        cols = [c for c in extra if c not in frame.columns and c not in TAU_COLUMNS.values()]
        if cols:
            log.warning("%s needs columns %s absent from the test trial; skipped", name, cols)
            continue
        dynamics[name] = (CoupledDynamics(est), frame[extra].to_numpy(float))
    # free runs, band members and horizon windows in one batch: all decoupled models together (they read tau and
    # merge into one call per RK4 stage), each coupled model alone (its own inputs)
    batches = [{n: (f, bands.get(n)) for n, (f, inputs) in dynamics.items() if inputs is tau}]
    batches += [{n: (f, None)} for n, (f, inputs) in dynamics.items() if inputs is not tau]
    results: dict[str, Any] = {}
    batches = list(filter(None, batches))
    with threadpool_limits(1, user_api="blas"):  # small per-step products: BLAS threads would only spin
        for k, batch in enumerate(batches, start=1):
            inputs = dynamics[next(iter(batch))][1]
            label = f"{', '.join(batch)} ({k}/{len(batches)})"
            results.update(run_models(batch, t_ns, nu, inputs, dofs, p.horizons_s, segment=seg,
                                      divergence_factor=p.divergence_factor, method=p.method,
                                      band_members=p.band_samples, progress=part_progress(progress, label)))
    runs, horizons = [], {}
    for name in dynamics:  # the models' order
        run, horizons[name] = results[name]
        runs.append(run)
    rows = None
    if {"u", "v"} <= set(dofs) and "yaw_rad" in frame:
        decoupled_f = {n: f for n, (f, inputs) in dynamics.items() if inputs is tau}
        with threadpool_limits(1, user_api="blas"):
            rows = bridge_outages(decoupled_f, t_ns, nu, tau, frame["yaw_rad"].to_numpy(float), dofs,
                                  p.outage_windows_s, segment=seg, divergence_factor=p.divergence_factor,
                                  method=p.method)
    return TrialRollout(t_ns, [VELOCITY_COLUMNS[d] for d in dofs], runs, horizons, rows)
