"""Bounded final fits (``coupled.svr_max_rows``): R² on the test trial, fit CPU time of the SVR models fitted with
every train_test row against at most N rows (evenly spaced in time), with the tune stage's hyperparameters.

    python bench/long_trials.py RUN --seeds 801 802 && auvid run --root RUN --vehicle RUN/vehicle.yaml --to tune
    python bench/final_rows.py RUN all 6000 4000 3000 2000
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from sklearn.metrics import r2_score
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline import store  # noqa: E402
from pipeline.config.params import CoupledParams  # noqa: E402
from pipeline.studies.coupled import build_model, model_inputs  # noqa: E402

MODELS = ("rbf_svr", "two_weights_svr", "wdse_svr", "graybox")


def main(argv: list[str]) -> None:
    if len(argv) < 2:
        raise SystemExit(__doc__)
    root, sizes = Path(argv[0]), [None if s == "all" else int(s) for s in argv[1:]]
    hyper = json.loads((root / "data/models/coupled/hyperparameters.json").read_text())["hyperparameters"]
    cp = CoupledParams()
    tt, te = store.load(root, split="train_test"), store.load(root, split="test")
    print(f"train_test rows {len(tt)}, test rows {len(te)}\n")
    print("| model | rows | fit CPU-s | R² " + " / ".join(cp.outputs) + " |\n| --- | --- | --- | --- |")
    for model in MODELS:
        cols = model_inputs(model, cp)
        X, y = tt[cols].to_numpy(float), tt[cp.outputs].to_numpy(float)
        Xt, yt = te[cols].to_numpy(float), te[cp.outputs].to_numpy(float)
        for n in sizes:
            est = build_model(model, hyper[model], CoupledParams(svr_max_rows=n), train=tt)
            with threadpool_limits(1):
                t0 = time.process_time()
                est.fit(X, y)
                fit = time.process_time() - t0
                pred = est.predict(Xt)
            r2 = " ".join(f"{r2_score(yt[:, k], pred[:, k]):.4f}" for k in range(len(cp.outputs)))
            print(f"| {model} | {min(len(X), n or len(X))} | {fit:.1f} | {r2} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
