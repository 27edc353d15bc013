"""A run of ``bench/long_trials.py`` (after ``auvid run``): its final SVRs and gray boxes with the tune stage at
``coupled.max_samples`` 600 (the run's own) and 1200 (tuned again on a copy), R² on the unseen trial t2 against
the differentiate targets and against the simulator's truth.

    python bench/score_subsample.py RUN COPY
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import store
from pipeline.config import Params
from pipeline.config.loading import load_vehicle
from pipeline.studies.coupled import build_model, model_inputs, rigid_body_uvr
from stages import tune

OUT = ["udot_mps2", "vdot_mps2", "rdot_radps2"]


def r2(pred: np.ndarray, true: np.ndarray) -> float:
    return float(1 - np.sum((true - pred) ** 2) / np.sum((true - true.mean()) ** 2))


def main(src: Path, copy: Path) -> None:
    vehicle = load_vehicle(src / "vehicle.yaml")
    truth = pd.read_parquet(src / "t2_truth.parquet").set_index("t_ns")
    res: dict = {}
    for n in (600, 1200):
        root = src if n == 600 else copy
        params = Params.model_validate({"features": {"test_trials": ["t2"]}, "coupled": {"max_samples": n}})
        if n != 600:
            shutil.rmtree(root, ignore_errors=True)
            shutil.copytree(src, root)
            tune.run(root, vehicle, params)
        cp = params.coupled
        hyper = json.loads((root / "data/models/coupled/hyperparameters.json").read_text())["hyperparameters"]
        tt = store.load(root, split="train_test")
        te = store.load(root, split="test").sort_values("t_ns")
        a_true = truth.loc[te["t_ns"].to_numpy()][OUT].to_numpy()
        for m in [m for m in cp.models if m in hyper]:  # the tuned ones: the SVRs and the gray boxes
            cols = model_inputs(m, cp)
            est = build_model(m, hyper[m], cp, train=tt, rigid_body_mass=rigid_body_uvr(vehicle.rigid_body))
            est.fit(tt[cols].to_numpy(float), tt[OUT].to_numpy(float))
            p = est.predict(te[cols].to_numpy(float))
            res.setdefault(m, {})[n] = {o: (round(r2(p[:, j], te[o].to_numpy()), 4),
                                            round(r2(p[:, j], a_true[:, j]), 4)) for j, o in enumerate(OUT)}
            print(m, n, res[m][n], flush=True)
    print(json.dumps(res))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
