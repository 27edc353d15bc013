"""The nested CV score under the old protocol (a whole search per fold, ``coupled.fold_evals: null``) and the new
one (a local search of ``fold_evals`` candidates from the tune stage's optimum), on validation seeds of simulated
trials: per seed three 180-s DAGON trials (seeds 100*SEED + 1..3, the third the test trial), sync at 10 Hz,
``coupled.folds: 3``, the code's defaults otherwise.

    python bench/cv_protocols.py 11 12
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from pipeline.config import Params
from pipeline.sim import DAGON_INFLOW_LOSS, generate_trial, load_example_vehicle, load_truth, write_trial
from stages import derive, differentiate, features, ingest, sync, train, tune


def one_seed(seed: int) -> dict:
    vehicle = load_example_vehicle()
    truth = dataclasses.replace(load_truth(), inflow_loss=DAGON_INFLOW_LOSS)
    base = Params.model_validate({"sync": {"rate_hz": 10.0}, "features": {"test_trials": ["s3"]},
                                  "coupled": {"folds": 3}})
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "run"
        (root / "data/raw").mkdir(parents=True)
        for k, name in enumerate(("s1", "s2", "s3")):
            trial = generate_trial(vehicle, 180.0, seed=100 * seed + k + 1, truth=truth, warmup_s=30.0,
                                   start_offset_s=1000.0 * k)
            write_trial(trial, "mcap", root / f"data/raw/{name}.mcap")
        for stage in (ingest, sync, differentiate, derive, features, tune):
            stage.run(root, vehicle, base)
        for label, fold_evals in (("old", None), ("new", 8)):
            run = Path(tmp) / label
            shutil.copytree(root, run)
            params = base.model_copy(update={"coupled": base.coupled.model_copy(update={"fold_evals": fold_evals})})
            t0, c0 = time.perf_counter(), time.process_time()
            train.run(run, vehicle, params)
            t3 = json.loads((run / "data/evaluation/coupled/table3.json").read_text())
            res[label] = {"wall_s": round(time.perf_counter() - t0, 1), "cpu_s": round(time.process_time() - c0, 1),
                          "cv": {m: {o: round(v["cv"][o]["test_r2"]["mean"], 4) for o in v["cv"]}
                                 for m, v in t3.items()},
                          "final": {m: {o: round(v["final"][o]["r2"], 4) for o in v["final"]}
                                    for m, v in t3.items()}}
            print(seed, label, json.dumps(res[label]), flush=True)
    return res


if __name__ == "__main__":
    print(json.dumps({seed: one_seed(seed) for seed in map(int, sys.argv[1:])}, indent=1))
