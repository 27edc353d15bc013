"""A feature store built from pipeline.sim trials through the real stages (ingest ... features)."""

from __future__ import annotations

import functools
from pathlib import Path

from pipeline.config import Params, Vehicle
from pipeline.sim import Controls, SensorOptions, SimTrial, SimTruth, generate_trial, load_example_vehicle, write_trial
from stages import derive, differentiate, features, ingest, sync

#: name -> (excitation, seed, duration s, DVL dropouts)
TrialSpec = tuple[str, int, float, bool]


def build_store(root: Path, specs: dict[str, TrialSpec], params: Params, amplitude_rpm: float = 3500.0,
                sensors: dict | None = None) -> tuple[Vehicle, dict[str, object]]:
    """Simulate each trial, write it as MCAP under ``data/raw``, and run the stages up to the feature store."""
    vehicle = load_example_vehicle()
    (root / "data/raw").mkdir(parents=True, exist_ok=True)
    trials = {}
    for name, (excite, seed, duration_s, dropouts) in specs.items():
        trial = generate_trial(vehicle, duration_s, seed=seed, controls=Controls(excite=excite,
                                                                                  amplitude_rpm=amplitude_rpm),
                               sensors=SensorOptions(dropouts=dropouts, **(sensors or {})))
        write_trial(trial, "mcap", root / f"data/raw/{name}.mcap")
        trials[name] = trial
    for stage in (ingest, sync, differentiate, derive, features):
        result = stage.run(root, vehicle, params)
        assert not result.quarantined, (stage.NAME, result.quarantined)
    return vehicle, trials


@functools.lru_cache(maxsize=16)
def cached_trial(seed: int, duration_s: float, *, truth: SimTruth | None = None, warmup_s: float = 0.0,
                 start_offset_s: float = 0.0, controls: Controls | None = None) -> SimTrial:
    """One simulated DAGON trial, computed once per test session (arguments are hashable: frozen dataclasses)."""
    return generate_trial(load_example_vehicle(), duration_s, seed=seed, truth=truth, warmup_s=warmup_s,
                          start_offset_s=start_offset_s, controls=controls)


def coupled_store(root: Path, trials: dict[str, int], duration_s: float, params: Params, *,
                  truth: SimTruth | None = None, warmup_s: float = 0.0) -> Vehicle:
    """The coupled study's feature store: simulated trials (``name -> seed``, 1000 s apart) written as signal
    tables, then sync ... features through the real stages. Trials come from :func:`cached_trial`."""
    from tests.store.test_stages_features import _run_all, _write_signals, signal_tables

    vehicle = load_example_vehicle()
    for k, (name, seed) in enumerate(trials.items()):
        trial = cached_trial(seed, duration_s, truth=truth, warmup_s=warmup_s, start_offset_s=1000.0 * k)
        _write_signals(root, name, signal_tables(trial, vehicle))
    _run_all(root, vehicle, params)
    return vehicle
