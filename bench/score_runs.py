"""Every saved coupled model of one or more runs of ``bench/long_trials.py`` (after ``auvid run``), scored on the
unseen trial t2 against the simulator's true accelerations: R² per output, one row per model, one column per run.

    python bench/score_runs.py RUN_A RUN_B
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import store
from pipeline.config import Params
from pipeline.models.card import load_model
from pipeline.studies.coupled import model_inputs

OUT = ["udot_mps2", "vdot_mps2", "rdot_radps2"]


def r2(pred: np.ndarray, true: np.ndarray) -> float:
    return float(1 - np.sum((true - pred) ** 2) / np.sum((true - true.mean()) ** 2))


def main(runs: list[Path]) -> None:
    params = Params().coupled
    scores: dict[str, dict[str, list[float]]] = {}
    for run in runs:
        truth = pd.read_parquet(run / "t2_truth.parquet").set_index("t_ns")
        test = store.load(run, split="test").sort_values("t_ns")
        true = truth.loc[test["t_ns"].to_numpy()][OUT].to_numpy()
        for path in sorted((run / "data/models/coupled").glob("*.joblib")):
            pred = load_model(path)[0].predict(test[model_inputs(path.stem, params)].to_numpy(float))
            scores.setdefault(path.stem, {})[run.name] = [round(r2(pred[:, j], true[:, j]), 4) for j in range(3)]
    print("| model | " + " | ".join(r.name for r in runs) + " |")
    print("| --- |" + " --- |" * len(runs))
    for model, per_run in scores.items():
        print(f"| {model} | " + " | ".join(" / ".join(f"{v:.4f}" for v in per_run.get(r.name, [])) for r in runs)
              + " |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main([Path(a) for a in sys.argv[1:]])
