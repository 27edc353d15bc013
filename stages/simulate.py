"""Simulate stage: fitted models + the test split -> data/simulation/ (free runs, horizons, DVL-outage bridging).

For every test trial: each decoupled model set (``data/models/decoupled/<dof>_<model>.joblib`` for all of
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
import pandas as pd
import pyarrow as pa

from pipeline import layout, physics, store
from pipeline.config import Params, Vehicle
from pipeline.errors import ModelError
from pipeline.simulate import (
    DOFS,
    TAU_COLUMNS,
    VELOCITY_COLUMNS,
    CoupledDynamics,
    DecoupledDynamics,
    band_tables,
    bridge_outages,
    bridging_markdown,
    damping_tables,
    plot_bridging,
    plot_free_runs,
    simulate_models,
    table_range,
)
from pipeline.tableio import atomic_path, write_json, write_parquet
from stages.common import StageResult, stage_main

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
    accels = [c.replace("_mps", "dot_mps2", 1) if c.endswith("_mps") else c.replace("_radps", "dot_radps2", 1)
              for c in states]
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


def _part(progress: Callable[..., Any] | None, label: str) -> Callable[..., Any] | None:
    """A progress callback for one part of the stage: the part's own done/total, ``label`` first in desc."""
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


def simulate_trial(frame: pd.DataFrame, vehicle: Vehicle, params: Params, decoupled: dict[str, dict[str, Any]],
                   coupled: dict[str, tuple[Any, list[str]]], out_dir: Path,
                   progress: Callable[..., Any] | None = None) -> tuple[dict[str, Any], list[Path]]:
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
    runs, horizons = [], {}
    # free runs, band members and horizon windows in one batch: all decoupled models together (they read tau and
    # merge into one call per RK4 stage), each coupled model alone (its own inputs)
    batches = [{n: (f, bands.get(n)) for n, (f, inputs) in dynamics.items() if inputs is tau}]
    batches += [{n: (f, None)} for n, (f, inputs) in dynamics.items() if inputs is not tau]
    results: dict[str, Any] = {}
    batches = list(filter(None, batches))
    for k, batch in enumerate(batches, start=1):
        inputs = dynamics[next(iter(batch))][1]
        label = f"{', '.join(batch)} ({k}/{len(batches)})"
        results.update(simulate_models(batch, t_ns, nu, inputs, dofs, p.horizons_s, segment=seg,
                                       divergence_factor=p.divergence_factor, method=p.method,
                                       band_members=p.band_samples, progress=_part(progress, label)))
    for name in dynamics:  # the models' order as before
        run, horizons[name] = results[name]
        runs.append(run)
    outputs = [write_json([r.summary() for r in runs], out_dir / "free_run.json"),
               write_json(horizons, out_dir / "horizons.json"),
               write_free_runs(t_ns, [VELOCITY_COLUMNS[d] for d in dofs], runs, out_dir / "free_run.parquet")]
    if runs:
        outputs.append(plot_free_runs(runs, out_dir / "free_run.png", title=str(frame["trial"].iloc[0])))
    summary: dict[str, Any] = {"free_run": [r.summary() for r in runs], "horizons": horizons}
    if {"u", "v"} <= set(dofs) and "yaw_rad" in frame:
        decoupled_f = {n: f for n, (f, inputs) in dynamics.items() if inputs is tau}
        rows = bridge_outages(decoupled_f, t_ns, nu, tau, frame["yaw_rad"].to_numpy(float), dofs,
                              p.outage_windows_s, segment=seg, divergence_factor=p.divergence_factor, method=p.method)
        outputs.append(write_json(rows, out_dir / "bridging.json"))
        with atomic_path(out_dir / "bridging.md") as tmp:
            tmp.write_text(bridging_markdown(rows))
        outputs += [out_dir / "bridging.md", plot_bridging(rows, out_dir / "bridging.png")]
        summary["bridging"] = rows
    return summary, outputs


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
    dofs = list(params.decoupled.dofs)
    test = store.load(root, vehicle=vehicle.name, split="test")
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
        summary, paths = simulate_trial(frame.reset_index(drop=True), vehicle, params, decoupled, coupled,
                                        root / layout.SIMULATION / str(trial),
                                        _part(progress, f"trial {trial} ({k}/{len(groups)}):"))
        metrics[str(trial)] = summary
        outputs += paths
    outputs.append(write_json(metrics, root / layout.SIMULATION / "metrics.json"))
    status = {f"{t}/{r['model']}": r["status"] for t, s in metrics.items() for r in s["free_run"]}
    return StageResult(stage=NAME, outputs=outputs, summary={"status": status})


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
