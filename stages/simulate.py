"""Simulate stage: fitted models + the test split -> data/simulation/ (free runs, horizons, DVL-outage bridging).

For every test trial (:func:`pipeline.rollout.rollout_trial`; tables and figures: :mod:`pipeline.report.rollout`):
each decoupled model set (``data/models/decoupled/<dof>_<model>.joblib`` for all of
``decoupled.dofs``) becomes ``M nudot = tau - C(nu) nu - d(nu)`` with M and C from ``pipeline.physics`` and tau
from the measured thruster speeds (``physics.generalized_forces``; minus ``physics.restoring_force`` when roll and
pitch are in the store); each coupled model of ``stages.train`` (``data/models/coupled/<name>.joblib`` + card
``<name>.card.json`` whose ``inputs`` are the velocity columns of those DOFs first, then thruster speeds or ``tau_*``
columns) is rolled out as ``nudot = F(nu, inputs)``. Writes ``data/simulation/<trial>/``: ``free_run.json|png``,
``free_run.parquet`` (the trajectories per sample), ``horizons.json``, ``bridging.json|md|png``, and
``data/simulation/metrics.json`` (all trials, deterministic).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from pipeline import layout, store
from pipeline.config import Params, Vehicle, coupled_skip_reason
from pipeline.errors import ModelError
from pipeline.report.rollout import bridging_markdown, plot_bridging, plot_free_runs
from pipeline.rollout import TrialRollout, part_progress, rollout_trial
from pipeline.skips import clear_skip
from pipeline.tableio import atomic_path, remove_stale_temps, write_json, write_parquet
from pipeline.vocabulary import VELOCITY_COLUMNS, acceleration_column
from stages.common import StageResult, skipped_result, stage_main

NAME = "simulate"
log = logging.getLogger(__name__)


def decoupled_models(root: Path, dofs: list[str], wanted: list[str] | None) -> dict[str, dict[str, Any]]:
    """``{model: {dof: estimator}}`` for every model fitted for all ``dofs``, each loaded through its card
    (ModelError for a ``.joblib`` without a card that records its sha256: docs/security.md)."""
    from pipeline.models.card import load_model

    base = Path(root) / layout.MODELS / "decoupled"
    names = sorted({p.stem.split("_", 1)[1] for p in base.glob("*_*.joblib")}) if base.exists() else []
    out = {}
    for name in names if wanted is None else wanted:
        paths = {d: base / f"{d}_{name}.joblib" for d in dofs}
        if all(p.exists() for p in paths.values()):
            out[name] = {d: load_model(p)[0] for d, p in paths.items()}  # sha256 checked against the card
        else:
            log.warning("decoupled model %r lacks DOF(s) %s; skipped", name, [d for d, p in paths.items()
                                                                            if not p.exists()])
    return out


def coupled_models(root: Path, dofs: list[str]) -> dict[str, tuple[Any, list[str]]]:
    """``{name: (estimator, extra input columns)}`` for the coupled models ``stages.train`` wrote.

    Each is ``data/models/coupled/<name>.joblib`` with its model card ``<name>.card.json``
    (:mod:`pipeline.models.card`: ``inputs``, ``outputs``, sha256 of the pickle, checked at load). A model is
    used when its inputs start with the velocity columns of the simulated DOFs and its outputs are their
    accelerations in the same order; the remaining inputs (thruster speeds or ``tau_*``) are read per sample.
    """
    from pipeline.models.card import load_model

    base = Path(root) / layout.MODELS / "coupled"
    states = [VELOCITY_COLUMNS[d] for d in dofs]
    accels = [acceleration_column(d) for d in dofs]
    out = {}
    for card_path in sorted(base.glob("*.card.json")) if base.exists() else []:
        name = card_path.name.removesuffix(".card.json")
        try:
            card = json.loads(card_path.read_text())
        except json.JSONDecodeError:
            log.warning("unreadable model card %s; skipped", card_path)
            continue
        inputs, outputs = card.get("inputs"), card.get("outputs")
        if not isinstance(inputs, list) or inputs[: len(states)] != states or outputs != accels:
            log.info("coupled model %r (inputs %s, outputs %s) does not fit DOFs %s; skipped", name, inputs,
                     outputs, dofs)
            continue
        estimator, _ = load_model(base / Path(str(card.get("model_file", f"{name}.joblib"))).name)
        out[f"coupled_{name}"] = (estimator, inputs[len(states):])
    return out


def write_trial_outputs(result: TrialRollout, trial: str, out_dir: Path) -> list[Path]:
    """The files of one trial's rollouts: ``free_run.json|parquet|png``, ``horizons.json`` and, when the trial was
    bridged, ``bridging.json|md|png``."""
    runs = result.runs
    outputs = [write_json([r.summary() for r in runs], out_dir / "free_run.json"),
               write_json(result.horizons, out_dir / "horizons.json"),
               write_free_runs(result.t_ns, result.columns, runs, out_dir / "free_run.parquet")]
    if runs:
        outputs.append(plot_free_runs(runs, out_dir / "free_run.png", title=trial))
    if result.bridging is not None:
        rows = result.bridging
        outputs.append(write_json(rows, out_dir / "bridging.json"))
        with atomic_path(out_dir / "bridging.md") as tmp:
            tmp.write_text(bridging_markdown(rows))
        outputs += [out_dir / "bridging.md", plot_bridging(rows, out_dir / "bridging.png")]
    return outputs


def write_free_runs(t_ns: np.ndarray, columns: list[str], runs: list[Any], target: Path) -> Path:
    """The free-run trajectories per sample (for ``auvid export``): ``t_ns``, the measured velocities under their
    own names, and per model ``<model>/<column>`` (NaN where not simulated) and, with a band,
    ``<model>/<column>/lower`` and ``/upper`` (mean -+ 2 sd of the posterior members)."""
    data: dict[str, Any] = {"t_ns": pa.array(t_ns, pa.int64())}
    if runs:
        data.update({c: runs[0].measured[:, j] for j, c in enumerate(columns)})
    for r in runs:
        for j, c in enumerate(columns):
            data[f"{r.name}/{c}"] = r.predicted[:, j]
            if r.band is not None:
                data[f"{r.name}/{c}/lower"], data[f"{r.name}/{c}/upper"] = r.band[0][:, j], r.band[1][:, j]
    return write_parquet(pa.table(data), target, {"stage": NAME, "models": [r.name for r in runs]})


def run(root: Path, vehicle: Vehicle, params: Params, progress: Callable[..., Any] | None = None) -> StageResult:
    """Free-run the fitted models on each test trial; horizons; DVL-outage bridging. ``progress``: the rollout
    steps of each trial's batches (stages.common)."""
    root = Path(root)
    remove_stale_temps(root / layout.SIMULATION, recursive=True)
    dofs = list(params.decoupled.dofs)
    test = store.load(root, vehicle=vehicle.name, split="test")
    if test.empty and coupled_skip_reason(vehicle, params) is not None:
        # the decoupled study alone (a heave-only ROV): its damping and B - W need no unseen trial, its free runs do
        return skipped_result(NAME, [root / layout.SIMULATION], (NAME,), (
            "no unseen trial (features.test_trials is empty): the free runs roll the damping models out on a trial "
            "they were not fitted on; name one of the run's trials in features.test_trials to have them"))
    clear_skip([root / layout.SIMULATION])
    if test.empty:
        raise ModelError(f"no test-split rows for vehicle {vehicle.name!r} (set features.test_trials)",
                         file=layout.features_dir(root))
    decoupled = decoupled_models(root, dofs, params.simulate.models)
    coupled = coupled_models(root, dofs)
    if not decoupled and not coupled:
        raise ModelError("no fitted models (run the decoupled or coupled stage first)", file=Path(layout.MODELS))
    outputs: list[Path] = []
    metrics = {}
    groups = list(test.groupby("trial", sort=True))
    for k, (trial, frame) in enumerate(groups, start=1):
        frame = frame.reset_index(drop=True)
        result = rollout_trial(frame, vehicle, params, decoupled, coupled,
                               part_progress(progress, f"trial {trial} ({k}/{len(groups)}):"))
        metrics[str(trial)] = result.summary()
        outputs += write_trial_outputs(result, str(frame["trial"].iloc[0]), root / layout.SIMULATION / str(trial))
    outputs.append(write_json(metrics, root / layout.SIMULATION / "metrics.json"))
    status = {f"{t}/{r['model']}": r["status"] for t, s in metrics.items() for r in s["free_run"]}
    return StageResult(stage=NAME, outputs=outputs, summary={"status": status})


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
