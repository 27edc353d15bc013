"""A feature store built from pipeline.sim trials through the real stages (ingest ... features)."""

from __future__ import annotations

from pathlib import Path

from pipeline.config import Params, Vehicle
from pipeline.sim import Controls, SensorOptions, load_example_vehicle, simulate_trial, write_trial
from stages import derive, differentiate, features, ingest, sync

#: name -> (excitation, seed, duration s, DVL dropouts)
TrialSpec = tuple[str, int, float, bool]


def build_store(root: Path, specs: dict[str, TrialSpec], params: Params, amplitude_rpm: float = 3500.0
                ) -> tuple[Vehicle, dict[str, object]]:
    """Simulate each trial, write it as MCAP under ``data/raw``, and run the stages up to the feature store."""
    vehicle = load_example_vehicle()
    (root / "data/raw").mkdir(parents=True, exist_ok=True)
    trials = {}
    for name, (excite, seed, duration_s, dropouts) in specs.items():
        trial = simulate_trial(vehicle, duration_s, seed=seed, controls=Controls(excite=excite,
                                                                                  amplitude_rpm=amplitude_rpm),
                               sensors=SensorOptions(dropouts=dropouts))
        write_trial(trial, "mcap", root / f"data/raw/{name}.mcap")
        trials[name] = trial
    for stage in (ingest, sync, differentiate, derive, features):
        result = stage.run(root, vehicle, params)
        assert not result.quarantined, (stage.NAME, result.quarantined)
    return vehicle, trials
