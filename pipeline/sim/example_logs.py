"""The embedded example: simulated DAGON trials written as logs, with their truth tables and ``vehicle.yaml`` (what
``auvid demo`` and the ``example`` stage lay out as a run directory)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import yaml

from pipeline.sim.trial import example_vehicle_path, generate_trial, load_example_vehicle
from pipeline.sim.writers import EXTENSIONS, csv_vehicle, write_trial
from pipeline.tableio import write_parquet


@dataclass(frozen=True)
class ExamplePaths:
    """What :func:`example` wrote: the vehicle config, the trial logs, the truth tables (Parquet)."""

    vehicle: Path
    trials: list[Path]
    truth: list[Path]


def example(out_dir: str | Path, fmt: str = "mcap", duration_s: float = 180.0, seed: int = 0,
            n_trials: int = 3) -> ExamplePaths:
    """Write ``n_trials`` simulated DAGON trials (``trial01`` ...; the last one is meant as the unseen test
    trial), their truth tables (``truth/<trial>.parquet``) and ``vehicle.yaml`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    vehicle = load_example_vehicle()
    trials, truths = [], []
    for i in range(n_trials):
        trial_id = f"trial{i + 1:02d}"
        trial = generate_trial(vehicle, duration_s=duration_s, seed=seed * 1000 + i, start_offset_s=3600.0 * i)
        trials.append(write_trial(trial, fmt, out / f"{trial_id}{EXTENSIONS[fmt]}", overwrite=True))
        truths.append(write_parquet(pa.Table.from_pandas(trial.truth, preserve_index=False),
                                    out / "truth" / f"{trial_id}.parquet",
                                    {"trial": trial_id, "source": "pipeline.sim", "seed": trial.seed,
                                     "duration_s": duration_s}))
    vehicle_path = out / "vehicle.yaml"
    if fmt == "csv":
        text = "# DAGON-like AUV, CSV layout, written by pipeline.sim.example\n" + yaml.safe_dump(
            csv_vehicle(vehicle).model_dump(mode="json"), sort_keys=False)
    else:
        text = example_vehicle_path().read_text(encoding="utf-8")
    vehicle_path.write_text(text, encoding="utf-8")
    return ExamplePaths(vehicle_path, trials, truths)
