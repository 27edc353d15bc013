"""Calibration of the decoupled GP over many simulated trial sets: does its 2-sigma band cover the true damping?

    python bench/decoupled_coverage.py                  # 8 seed sets, the default differentiate params
    python bench/decoupled_coverage.py --configs default corrected     # the table of docs/models.md

Each seed set is three single-DOF trials of the project's simulator (surge 120 s, sway 45 s, yaw 100 s, DVL
drop-outs on; the trials of tests/rollout/test_decoupled_sim.py with seeds 11 + 100 k ...) written as MCAP and taken
through the real stages (ingest ... features). On each DOF's train_test rows (at most 400, as the test) it fits LS and
the GP with and without the (nu, nu|nu|) warp, and scores the curves on 2-98 % of the DOF's velocities against the
simulator's true damping: coverage = fraction of the curve inside mean +- 2 sd, errors = mean |curve - truth|.
Configs: ``default`` = the default differentiate params (plain Gaussian derivative, 0.25 s); ``corrected`` = the
bias-corrected kernel (``gaussian_degree: 4``) at 0.35 s, ``corrected-0.25`` the same at 0.25 s. Prints one
markdown row per (config, GP inputs, DOF).

    python bench/decoupled_coverage.py --intervals --seeds 4 --first 0      # validation seed sets 0..3
    python bench/decoupled_coverage.py --intervals --seeds 4 --first 100    # test seed sets 100..103

``--intervals``: the prediction intervals on an unseen trial. Each seed set is the three single-DOF training trials
(as above, the paper's excitation, periods 6-45 s) and one unseen test trial per DOF from another regime (one
sinusoid, periods 5-18 s, same duration), through the real stages with the code's defaults; the study (every model,
the code's defaults) learns each DOF from its training trial and is scored on its test trial: the share of the test
trial's damping targets inside each model's 90 % interval and inside the GP's 2-sigma band. Prints mean and worst
case over the seed sets per (model, DOF). Seed sets 0-99 served as validation (every choice), 100+ as test.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT,):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

CONFIGS = {"default": {}, "corrected": {"gaussian_degree": 4, "sigma_s": 0.35},
           "corrected-0.25": {"gaussian_degree": 4, "sigma_s": 0.25}}
DOF_INDEX = {"u": 0, "v": 1, "r": 5}
TRIALS = {"u": "surge", "v": "sway", "r": "yaw"}


def true_curve(dof: str, x: np.ndarray) -> np.ndarray:
    from pipeline.sim import true_damping

    nu = np.zeros((len(x), 6))
    nu[:, DOF_INDEX[dof]] = x
    return true_damping(nu)[:, DOF_INDEX[dof]]


def seed_set(root: Path, k: int, differentiate: dict) -> dict[str, object]:
    """The train_test rows of each DOF's trial for seed set ``k``."""
    from pipeline import store
    from pipeline.config import Params
    from tests.studies.helpers import build_store

    params = Params(features={"test_trials": []}, differentiate=differentiate)
    specs = {"surge": ("surge", 11 + 100 * k, 120.0, True), "sway": ("sway", 12 + 100 * k, 45.0, True),
             "yaw": ("yaw", 13 + 100 * k, 100.0, True)}
    build_store(root, specs, params)
    return {dof: store.load(root, trials=trial, split="train_test") for dof, trial in TRIALS.items()}


def score(data: object, dof: str) -> dict[str, float]:
    from pipeline.models.decoupled import DampingGP, LinearQuadraticDamping
    from pipeline.studies.decoupled import dof_data

    X, y = dof_data(data, dof, 400)
    x = X[:, 0]
    lo, hi = np.quantile(x, [0.02, 0.98])
    grid = np.linspace(x.min(), x.max(), 101)
    grid = grid[(grid >= lo) & (grid <= hi)]
    truth = true_curve(dof, grid)
    out = {"ls_err": float(np.mean(np.abs(LinearQuadraticDamping().fit(X, y).predict(grid[:, None]) - truth)))}
    for warp in ("none", "signed_square"):
        mean, sd = DampingGP(max_samples=400, warp=warp).fit(X, y).predict(grid[:, None], return_std=True)
        out[f"{warp}_cov"] = float(np.mean(np.abs(mean - truth) <= 2 * sd))
        out[f"{warp}_err"] = float(np.mean(np.abs(mean - truth)))
    return out


def interval_set(root: Path, k: int) -> dict[str, dict[str, dict[str, float]]]:
    """Seed set ``k`` of ``--intervals``: ``{dof: {model: test-trial scores}}``."""
    from pipeline import store
    from pipeline.config import Params
    from pipeline.config.params import DecoupledParams
    from pipeline.sim import Controls, SensorOptions, generate_trial, load_example_vehicle, write_trial
    from pipeline.studies.decoupled import run_study
    from stages import derive, differentiate, features, ingest, sync

    vehicle = load_example_vehicle()
    durations = {"u": 120.0, "v": 45.0, "r": 100.0}
    (root / "data/raw").mkdir(parents=True, exist_ok=True)
    for j, dof in enumerate(DOF_INDEX):
        for tag, seed, controls in (
                ("train", 11 + j + 100 * k, Controls(excite=TRIALS[dof], amplitude_rpm=3500.0)),
                ("test", 51 + j + 100 * k, Controls(excite=TRIALS[dof], amplitude_rpm=3500.0, n_sines=1,
                                                    period_range_s=(5.0, 18.0)))):
            trial = generate_trial(vehicle, durations[dof], seed=seed, controls=controls,
                                   sensors=SensorOptions(dropouts=True))
            write_trial(trial, "mcap", root / f"data/raw/{dof}_{tag}.mcap")
    params = Params(features={"test_trials": [f"{d}_test" for d in DOF_INDEX]})
    for stage in (ingest, sync, differentiate, derive, features):
        stage.run(root, vehicle, params)
    frame = store.load(root)
    p = DecoupledParams()
    out = {}
    for dof in DOF_INDEX:
        tt = frame[(frame["trial"] == f"{dof}_train") & (frame["split"] == "train_test")]
        tu = frame[(frame["trial"] == f"{dof}_train") & (frame["split"] == "tuning")]
        study = run_study(tu, tt, dofs=[dof], models=p.models, folds=p.folds, search=p.search,
                          gp_max_samples=p.gp_max_samples, max_samples=p.max_samples, curve_points=2, seed=p.seed,
                          gp_warp=p.gp_warp, test=frame[frame["trial"] == f"{dof}_test"])
        out[dof] = {r.model: {**r.test, "half_width": r.interval["half_width"],
                              "cv_band": r.interval.get("cv_band_coverage")} for r in study.results}
    return out


def intervals(seeds: range) -> int:
    start = time.perf_counter()
    rows: dict[tuple[str, str], list[dict[str, float]]] = {}
    with tempfile.TemporaryDirectory(prefix="auvid-intervals-") as tmp:
        for k in seeds:
            for dof, models in interval_set(Path(tmp) / f"set{k}", k).items():
                for model, scores in models.items():
                    rows.setdefault((model, dof), []).append(scores)
            print(f"# seed set {k} done ({time.perf_counter() - start:.0f} s)", file=sys.stderr)
    print(f"seed sets {seeds.start}..{seeds.stop - 1}")
    alts = ("prediction", "sd_prediction")
    print("| model | DOF | 90 % inside: mean | worst | GP 2σ inside: mean | worst | GP 2σ in CV | "
          + " | ".join(f"{a}: mean | worst" for a in alts) + " |")
    print("|---|---|---|---|---|---|---|" + "---|---|" * len(alts))
    cells = {k: [] for k in ("method", *alts)}
    for (model, dof), runs in sorted(rows.items(), key=lambda kv: (list(DOF_INDEX).index(kv[0][1]), kv[0][0])):
        cov = np.array([r["interval_coverage"] for r in runs])
        band = [r["band_coverage"] for r in runs if "band_coverage" in r]
        cvb = [r["cv_band"] for r in runs if r.get("cv_band") is not None]
        gp = (f"{np.mean(band):.3f} | {np.min(band):.3f} | {np.mean(cvb):.3f}" if band else "– | – | –")
        alt = {a: np.array([r.get(f"interval_coverage_{a}", np.nan) for r in runs]) for a in alts}
        cells["method"] += cov.tolist()
        for a in alts:
            cells[a] += alt[a].tolist()
        print(f"| {model} | {dof} | {cov.mean():.3f} | {cov.min():.3f} | {gp} | "
              + " | ".join(f"{alt[a].mean():.3f} | {alt[a].min():.3f}" for a in alts) + " |")
    for k, v in cells.items():  # every (seed set, model, DOF)
        v = np.array(v)
        print(f"{k}: {np.sum((v >= 0.85) & (v <= 0.95))} of {v.size} (seed set, model, DOF) inside 85-95 %, "
              f"{np.sum(v < 0.85)} under, {np.sum(v > 0.95)} over")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--first", type=int, default=0, help="--intervals: the first seed set")
    parser.add_argument("--intervals", action="store_true", help="prediction intervals on unseen trials")
    parser.add_argument("--configs", nargs="+", choices=sorted(CONFIGS), default=["default"])
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if args.intervals:
        return intervals(range(args.first, args.first + args.seeds))
    rows: dict[tuple[str, str], list[dict[str, float]]] = {}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="auvid-coverage-") as tmp:
        for config in args.configs:
            for k in range(args.seeds):
                data = seed_set(Path(tmp) / f"{config}{k}", k, CONFIGS[config])
                for dof in DOF_INDEX:
                    rows.setdefault((config, dof), []).append(score(data[dof], dof))
                print(f"# {config} seed set {k} done ({time.perf_counter() - start:.0f} s)", file=sys.stderr)
    print("| differentiate | GP inputs | DOF | coverage mean | coverage min | GP err | LS err | GP/LS |")
    print("|---|---|---|---|---|---|---|---|")
    for (config, dof), runs in rows.items():
        ls = np.array([r["ls_err"] for r in runs])
        for warp, label in (("none", "nu (paper)"), ("signed_square", "(nu, nu abs nu)")):
            cov = np.array([r[f"{warp}_cov"] for r in runs])
            err = np.array([r[f"{warp}_err"] for r in runs])
            print(f"| {config} | {label} | {dof} | {cov.mean():.2f} | {cov.min():.2f} | {err.mean():.3f} | "
                  f"{ls.mean():.3f} | {np.mean(err / ls):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
