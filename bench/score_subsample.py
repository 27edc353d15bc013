"""A run of ``bench/long_trials.py`` (after ``auvid run``): its final SVRs and gray boxes with the tune stage at
``coupled.max_samples`` 600 (the run's own) and 1200 (tuned again on a copy), R² on the unseen trial t2 against
the differentiate targets and against the simulator's truth.

    python bench/score_subsample.py RUN COPY
    python bench/score_subsample.py RUN COPY --phases 0 0.5     # each size also on rows shifted half a stride

``--phases``: the searches' rows are ``max_samples`` evenly spaced rows of the block; phase p starts them p of a
stride later (0: the code's rows). Every size and phase other than (600, 0) is tuned again on COPY. The spread
of one size over phases is the search's own reproducibility: how much a cell moves when nothing but which rows
of a slowly varying signal it sees changes.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import store
from pipeline.config import Params
from pipeline.config.loading import load_vehicle
from pipeline.studies import coupled
from pipeline.studies.coupled import build_model, model_inputs, rigid_body_uvr
from stages import tune

OUT = ["udot_mps2", "vdot_mps2", "rdot_radps2"]


def r2(pred: np.ndarray, true: np.ndarray) -> float:
    return float(1 - np.sum((true - pred) ** 2) / np.sum((true - true.mean()) ** 2))


def shifted_rows(phase: float):  # noqa: ANN201  (a stand-in for coupled._search_rows)
    """``coupled._search_rows`` with its evenly spaced rows started ``phase`` of a stride later."""
    original = coupled._search_rows

    def rows(frame: pd.DataFrame, params):  # noqa: ANN001, ANN202
        n = params.max_samples
        if phase == 0 or n is None or len(frame) <= n:
            return original(frame, params)
        stride = (len(frame) - 1) / (n - 1)
        at = np.minimum(np.linspace(0, len(frame) - 1, n) + phase * stride, len(frame) - 1)
        picked = frame.iloc[np.unique(at.round().astype(int))]
        return original(picked, params.model_copy(update={"max_samples": None}))

    return rows


def main(src: Path, copy: Path, phases: list[float]) -> None:
    vehicle = load_vehicle(src / "vehicle.yaml")
    truth = pd.read_parquet(src / "t2_truth.parquet").set_index("t_ns")
    res: dict = {}
    original = coupled._search_rows
    for n in (600, 1200):
        for phase in phases:
            root = src if (n, phase) == (600, 0) else copy
            params = Params.model_validate({"features": {"test_trials": ["t2"]}, "coupled": {"max_samples": n}})
            if root == copy:
                shutil.rmtree(root, ignore_errors=True)
                shutil.copytree(src, root)
                coupled._search_rows = shifted_rows(phase)
                try:
                    tune.run(root, vehicle, params)
                finally:
                    coupled._search_rows = original
            cp = params.coupled
            hyper = json.loads((root / "data/models/coupled/hyperparameters.json").read_text())["hyperparameters"]
            tt = store.load(root, split="train_test")
            te = store.load(root, split="test").sort_values("t_ns")
            a_true = truth.loc[te["t_ns"].to_numpy()][OUT].to_numpy()
            key = f"{n}" if phase == 0 else f"{n}+{phase:g}"
            for m in [m for m in cp.models if m in hyper]:  # the tuned ones: the SVRs and the gray boxes
                cols = model_inputs(m, cp)
                est = build_model(m, hyper[m], cp, train=tt, rigid_body_mass=rigid_body_uvr(vehicle.rigid_body))
                est.fit(tt[cols].to_numpy(float), tt[OUT].to_numpy(float))
                p = est.predict(te[cols].to_numpy(float))
                res.setdefault(m, {})[key] = {o: (round(r2(p[:, j], te[o].to_numpy()), 4),
                                                  round(r2(p[:, j], a_true[:, j]), 4)) for j, o in enumerate(OUT)}
                print(m, key, res[m][key], flush=True)
    print(json.dumps(res))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("copy", type=Path)
    ap.add_argument("--phases", type=float, nargs="+", default=[0.0])
    args = ap.parse_args()
    main(args.run, args.copy, args.phases)
