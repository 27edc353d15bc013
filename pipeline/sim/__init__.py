"""The project's own vehicle and sensor simulator: ground truth for the tests and the embedded example.

```python
from pipeline.sim import generate_trial, load_example_vehicle, write_trial
trial = generate_trial(load_example_vehicle(), duration_s=120.0, seed=1)
hard = generate_trial(load_example_vehicle(), duration_s=120.0, seed=3201, preset="hard")  # outruns its sensors
one = generate_trial(load_example_vehicle(), duration_s=120.0, seed=6401, preset="family")  # its own regime
one.regime.describe()  # '2 sines/thruster, periods 5-45 s, 2600 rpm (full), tether on, Hall speeds on'
trial.truth            # DataFrame at the integration rate (t_ns, u_mps ... d_r_Nm), docs/contracts.md names
trial.streams["dvl"]   # the DVL messages: log_ns, header_ns, fields by field path
write_trial(trial, "mcap", "trial01.mcap")
```

The packaged vehicle (``dagon.yaml``) is what a user knows; the true damping (``dagon_truth.yaml``,
:class:`SimTruth`) is what they do not. ``example(out_dir)`` writes trials + ``vehicle.yaml`` for the demo.
"""

from __future__ import annotations

from pipeline.sim.disturbance import Disturbance
from pipeline.sim.regime import Regime, draw_regime
from pipeline.sim.sensors import SensorOptions, Stream, StreamSpec, dvl_measurement
from pipeline.sim.trial import (
    EPOCH_NS,
    PRESET_SEED_OFFSET,
    PRESETS,
    SimTrial,
    example_vehicle_path,
    generate_trial,
    load_example_vehicle,
    truth_table,
)
from pipeline.sim.truth import DAGON_INFLOW_LOSS, CoupledTerm, SimTruth, load_truth, true_damping
from pipeline.sim.vehicle import Controls

__all__ = [
    "Controls", "CoupledTerm", "DAGON_INFLOW_LOSS", "Disturbance", "PRESETS", "PRESET_SEED_OFFSET", "Regime",
    "SensorOptions", "draw_regime", "SimTrial", "SimTruth", "Stream", "StreamSpec",
    "dvl_measurement", "example", "example_vehicle_path", "load_example_vehicle", "load_truth", "generate_trial",
    "true_damping", "truth_table", "write_trial", "FORMATS", "EPOCH_NS",
]


def __getattr__(name: str):  # lazy: writers import the ROS type system only when needed
    if name in ("write_trial", "FORMATS"):
        from pipeline.sim import writers

        return getattr(writers, name)
    if name == "example":
        from pipeline.sim.example_logs import example

        return example
    raise AttributeError(name)
