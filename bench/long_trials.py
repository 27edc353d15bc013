"""Two 480-s DAGON trials of ``pipeline.sim`` (seeds 701, 702: test data, chosen by nothing) as raw MCAP logs, with
the packaged vehicle config and params that give only ``features.test_trials`` (the code's defaults otherwise).

    python bench/long_trials.py RUN                    # then: auvid run --root RUN --vehicle RUN/vehicle.yaml
    python bench/long_trials.py RUN --seeds 801 802    # the validation pair a default is chosen on
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

from pipeline.sim import (
    DAGON_INFLOW_LOSS,
    example_vehicle_path,
    generate_trial,
    load_example_vehicle,
    load_truth,
    write_trial,
)


def main(root: Path, seeds: tuple[int, int] = (701, 702)) -> None:
    (root / "data/raw").mkdir(parents=True, exist_ok=True)
    vehicle = load_example_vehicle()
    truth = dataclasses.replace(load_truth(), inflow_loss=DAGON_INFLOW_LOSS)
    for k, name in enumerate(("t1", "t2")):
        trial = generate_trial(vehicle, 480.0, seed=seeds[k], truth=truth, warmup_s=30.0,
                               start_offset_s=1000.0 * k)
        write_trial(trial, "mcap", root / f"data/raw/{name}.mcap")
        trial.truth.to_parquet(root / f"{name}_truth.parquet")
    shutil.copy(example_vehicle_path(), root / "vehicle.yaml")
    (root / "params.yaml").write_text("features:\n  test_trials: [t2]\n")


if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) == 4 and args[1] == "--seeds":
        main(Path(args[0]), (int(args[2]), int(args[3])))
    elif len(args) == 1:
        main(Path(args[0]))
    else:
        raise SystemExit("usage: python bench/long_trials.py RUN [--seeds A B]")
