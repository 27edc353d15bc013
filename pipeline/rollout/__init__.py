"""Rollouts of learned motion models (the simulate stage's library): free runs of velocity, error growth per
horizon, and DVL-outage bridging.

- :mod:`~pipeline.rollout.tables`: learned 1-D damping models as lookup tables (and per-member tables of a band);
- :mod:`~pipeline.rollout.dynamics`: the dynamics a rollout steps (decoupled ``M nudot = tau - C nu - d``, coupled
  ``nudot = F(nu, inputs)``), and several stacked as one batch;
- :mod:`~pipeline.rollout.integrate`: the batched integrator (RK4 of :mod:`pipeline.rk4`, or Euler);
- :mod:`~pipeline.rollout.runs`: free runs, horizon errors, the GP's band;
- :mod:`~pipeline.rollout.bridging`: dead reckoning through simulated DVL outages;
- :mod:`~pipeline.rollout.trial`: the stage's pure function, :func:`rollout_trial`.

Tables and figures of the results: :mod:`pipeline.report.rollout`.
"""

from __future__ import annotations

from pipeline.rollout.bridging import bridge_outages, dead_reckon
from pipeline.rollout.dynamics import CoupledDynamics, DecoupledDynamics, Dynamics, MemberStack, fast_predictor, stack
from pipeline.rollout.integrate import rollout, rollout_ragged
from pipeline.rollout.runs import (
    FreeRun,
    divergence_bound,
    free_run,
    grid_step_s,
    horizon_errors,
    run_model,
    run_models,
    segment_runs,
    windows,
)
from pipeline.rollout.tables import Table1D, TableStack, band_tables, damping_tables, table_range, take
from pipeline.rollout.trial import TrialRollout, part_progress, rollout_trial, trial_inputs

__all__ = [
    "CoupledDynamics", "DecoupledDynamics", "Dynamics", "FreeRun", "MemberStack", "Table1D", "TableStack",
    "TrialRollout", "band_tables", "bridge_outages", "damping_tables", "dead_reckon", "divergence_bound",
    "fast_predictor", "free_run", "grid_step_s", "horizon_errors", "part_progress", "rollout", "rollout_ragged",
    "rollout_trial", "run_model", "run_models", "segment_runs", "stack", "table_range", "take", "trial_inputs",
    "windows",
]
