"""The coupled study on realistic simulated trials, scored against the simulator's TRUE accelerations.

Per seed: three DAGON trials from ``pipeline.sim`` with its default, realistic sensors (3.6 Hz DVL with 0.02 m/s
noise, outliers and lost lock, ...), sinusoidal thruster excitation, each cut from a run already in motion;
the truth has the propellers' thrust loss to inflow (outside the explicit models' family, as on a real vehicle;
``--no-inflow`` to switch it off: the forcing is then exact, but the truth's damping keeps terms neither
explicit model has — linear and cubic damping per DOF — so even then the truth is not inside their families).
Three presets (``--preset``, default gentle and hard): the simulator's default ("gentle": three summed sines per
thruster, periods 6-45 s), "hard" (one sine per thruster, periods 5-18 s, a tether-like disturbance, Hall-counter
thruster speeds, rate-sensor biases) and "family" (each trial draws its own regime from its seed,
``pipeline.sim.regime``: 1-3 sines per thruster, periods 5-45 s, half or full thrust, the tether on or off, Hall
speeds on or off, rate biases), each with its own seeds (``pipeline.sim.PRESET_SEED_OFFSET``).
Trials s1 and s2 are tuned and cross-validated on, s3 is the unseen test trial (``--train-trials N``: s1 ... sN,
the test trial s(N+1)). In the family preset the test trial's regime differs from every training trial's: where
its seed's draw has the same number of sines, thrust level, tether and Hall switches as one of theirs, it is
simulated from seed + 100000 k instead (k = 1, 2, ...: the first whose regime differs;
``pipeline.sim.regime.distinct_regime``), and the table says so. Validation seeds of
the family preset: 0-1, 20-21, 70-71; test seeds: 5-7, 22-24, 72-74 (2-4 retired; docs/models.md says which
served which). They go through the real stages
(ingest ... features, tune, train) with the code's defaults, what a user gets (``--params FILE`` for
others; the repository's ``params.yaml`` is the example's, sized for two cores, not the defaults).

On the test trial every model's prediction is scored (R²) against the simulator's true accelerations, next to
the **ceiling**: the simulator's true model evaluated at the same estimated inputs the models see (velocities
from the smoother, measured thruster speeds and attitude), scored against the same truth. The tables give the
mean and worst seed of each R², then each model's gap to the ceiling (ceiling - R² on the same seed), mean and
worst seed.

    python bench/coupled_study.py                               # 5 seeds x 480 s (long: ~10 min a seed)
    python bench/coupled_study.py --seeds 0 1 2 --duration 300 --models wdse_svr gertler_hagen
    python bench/coupled_study.py --no-cv                       # the same test scores, ~4x faster
    python bench/coupled_study.py --no-cv --preset hard --seeds 0 1
    python bench/coupled_study.py --no-cv --preset family --seeds 2 3 4 --duration 300   # the family's test seeds

``--no-cv`` runs the stages up to ``tune`` and then fits each model's final estimator on the train_test block
exactly as the train stage does (``pipeline.studies.coupled.build_model`` with the tuned hyperparameters), skipping
the train stage's cross-validation folds, which decide nothing the test trial sees: the scores are the same numbers.

``--intervals`` (needs the CV: not with ``--no-cv``) adds a table of each model's 90 % prediction interval
(``pipeline.studies.intervals``: split conformal on the train stage's out-of-fold |residuals|, the wider of the
blocked CV's and the held-out trials' quantiles, its spread growing with the prediction) and its share of the test
trial's MEASURED targets inside, mean and worst over seeds, beside the same share for the blocked CV's quantile alone
(one half-width) and for the alternative normalized by each target's own SD (``half_width_sd`` times the row's
SD); then, for the method and each calibration it was chosen among, how many (seed, model, output) cells lie inside
85-95 %, under and over.

    python bench/coupled_study.py --seeds 16 17 --duration 300 --intervals

``--oracle OUTPUT ...`` (a diagnostic, not a method): every WDSE-SVR candidate the tune stage's search scored for
that output (its ``search_trace.json``) is fitted on the train_test block as the final model is and scored against
the test trial's truth; the table gets a row with the best of them per seed, chosen on the test truth. It bounds
what a better choice among the searched hyperparameters could give the WDSE-SVR on these data (a row far above the
WDSE's says the search chose badly; one close to it, that the kernel and the data are the limit).

    python bench/coupled_study.py --no-cv --oracle vdot_mps2    # + 30 final fits a seed and output

``--loto`` (a diagnostic, not a method): each explicit model of the run fitted on all training trials but one and
scored (R² against the held-out trial's targets), per output; the table gets, per seed and output, the explicit model
a choice by the mean of those scores would take and its R² on the test truth, beside the best explicit model's.
It says whether a gray box whose base is chosen per output by held-out trials would do better than one base.

    python bench/coupled_study.py --no-cv --preset family --seeds 90 91 92 93 --duration 300 --loto \
        --models fossen gertler_hagen mcfarland_whitcomb

``--fossen-fits`` (a diagnostic): Fossen's model fitted on the training trials as the study fits it, with every
damping term (no selection), with the selection never removing an own-velocity damping term, and on the test trial
itself (every term: what its family can do on that motion); R² per output on the test trial's targets, and the
v̇ equation's damping coefficients of the study's fit.

    python bench/coupled_study.py --no-cv --preset family --seeds 92 99 --duration 300 --fossen-fits --models fossen
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline import store  # noqa: E402
from pipeline.config import Params  # noqa: E402
from pipeline.models.card import load_model  # noqa: E402
from pipeline.sim import (  # noqa: E402
    DAGON_INFLOW_LOSS,
    PRESET_SEED_OFFSET,
    PRESETS,
    generate_trial,
    load_example_vehicle,
    load_truth,
    write_trial,
)
from pipeline.sim.regime import family_trials  # noqa: E402
from pipeline.sim.vehicle import Dynamics  # noqa: E402

OUTPUTS = ("udot_mps2", "vdot_mps2", "rdot_radps2")
NU = ("u_mps", "v_mps", "w_mps", "p_radps", "q_radps", "r_radps")


def r2(pred: np.ndarray, true: np.ndarray) -> float:
    return float(1.0 - np.mean((pred - true) ** 2) / np.var(true))


def final_models(root: Path, params: Params, vehicle) -> dict:
    """The train stage's final estimators (fitted on the whole train_test block, the tune stage's hyperparameters,
    the smoother's SDs as the explicit models' weights), without its CV folds: model -> (estimator, inputs)."""
    from pipeline.studies.coupled import build_model, model_inputs, rigid_body_uvr
    from pipeline.vocabulary import NOISE_STD_COLUMNS

    cp = params.coupled
    hyper = json.loads((root / "data/models/coupled/hyperparameters.json").read_text())["hyperparameters"]
    tt = store.load(root, split="train_test").sort_values(["trial", "t_ns"])
    assert all(c in tt.columns for c in NOISE_STD_COLUMNS)
    out = {}
    for model in cp.models:
        cols = model_inputs(model, cp)
        est = build_model(model, hyper.get(model), cp, train=tt, rigid_body_mass=rigid_body_uvr(vehicle.rigid_body))
        out[model] = (est.fit(tt[cols].to_numpy(float), tt[cp.outputs].to_numpy(float)), cols)
    return out


def interval_shares(interval: dict, test, pred: np.ndarray) -> dict:
    """Per output: the share of the test trial's measured targets inside the model's 90 % interval, inside the
    calibrations the method was chosen among (:func:`_alternatives`) and inside the alternative normalized by the
    target's SD (q_sd times each row's SD; None without SD columns)."""
    from pipeline.evaluate import interval_half_width
    from pipeline.studies.intervals import target_sd

    sd = target_sd(test, OUTPUTS)
    out = {}
    for j, o in enumerate(OUTPUTS):
        err = np.abs(test[o].to_numpy(float) - pred[:, j])
        q_sd = interval[o].get("half_width_sd")
        out[o] = {"inside": float(np.mean(err <= interval_half_width(interval[o], sd[o], pred[:, j]))),
                  **{f"inside_{k}": float(np.mean(err <= q)) for k, q in _alternatives(interval[o]).items()},
                  "inside_sd": None if q_sd is None or sd[o] is None else float(np.mean(err <= q_sd * sd[o]))}
    return out


def _alternatives(interval: dict) -> dict:
    """The one-half-width calibrations the method was chosen among (docs/models.md, "Calibrated on held-out
    trials" and "A band that grows with the prediction"): the wider of the blocked CV's and the held-out trials'
    quantiles, the blocked CV's, the held-out trials' and the mean of both (each the blocked one's without
    held-out trials)."""
    q_b = interval.get("half_width_blocked", interval["half_width_constant"])
    q_t = interval.get("half_width_trials", q_b)
    return {"constant": interval["half_width_constant"], "blocked": q_b, "trials": q_t, "mean": 0.5 * (q_b + q_t)}


def oracle_scores(root: Path, params: Params, outputs: list[str], test, a_true: np.ndarray) -> dict:
    """Per output: the best R² against the truth over every WDSE-SVR candidate of the tune stage's search, each
    fitted on the train_test block as the final model is (its C scaled from the rows the search fitted)."""
    from pipeline.models.search import make_svr
    from pipeline.studies.coupled import model_inputs

    cp = params.coupled
    trace = json.loads((root / "data/evaluation/coupled/search_trace.json").read_text())["wdse_svr"]
    tt = store.load(root, split="train_test").sort_values(["trial", "t_ns"])
    cols = model_inputs("wdse_svr", cp)
    X, X_test = tt[cols].to_numpy(float), test[cols].to_numpy(float)
    out = {}
    for o in outputs:
        res = trace[o]
        scores = []
        for cand in res["trace"]:
            hp = {**cand["params"], "C_rows": res["best_params"]["C_rows"]}
            est = make_svr("wdse_svr", hp, cp.n_velocity_inputs(), cp.c_rate).fit(X, tt[o].to_numpy(float))
            scores.append(r2(est.predict(X_test), a_true[:, OUTPUTS.index(o)]))
        out[o] = {"best": max(scores), "n_candidates": len(scores)}
    return out


def _fit_scores(model: str, params: Params, vehicle, train, test, **settings) -> tuple[Any, list[float]]:
    """``model`` built as the train stage builds it (``settings`` on top), fitted on ``train``'s rows: the fitted
    estimator and its R² per output against ``test``'s targets."""
    from pipeline.studies.coupled import build_model, model_inputs, rigid_body_uvr

    cp = params.coupled
    cols = model_inputs(model, cp)
    est = build_model(model, None, cp, train=train, rigid_body_mass=rigid_body_uvr(vehicle.rigid_body))
    est.set_params(**settings).fit(train[cols].to_numpy(float), train[cp.outputs].to_numpy(float))
    pred = est.predict(test[cols].to_numpy(float))
    return est, [r2(pred[:, j], test[o].to_numpy(float)) for j, o in enumerate(cp.outputs)]


def loto_scores(root: Path, params: Params, vehicle) -> dict:
    """Per explicit model of the run: R² per output on each training trial's targets of the model fitted on the
    other training trials (the train stage's final fit, without that trial): model -> [[u̇, v̇, ṙ] per trial]."""
    from pipeline.studies.coupled import EXPLICIT_MODELS

    tt = store.load(root, split="train_test").sort_values(["trial", "t_ns"])
    return {model: [_fit_scores(model, params, vehicle, tt[tt["trial"] != held], tt[tt["trial"] == held])[1]
                    for held in sorted(tt["trial"].unique())]
            for model in params.coupled.models if model in EXPLICIT_MODELS}


def fossen_fits(root: Path, params: Params, vehicle) -> dict:
    """Fossen's fits of ``--fossen-fits`` (see the module's docstring): variant -> {"r2": [u̇, v̇, ṙ] on the test
    trial's targets, "terms": the selected terms (None without selection)}; "Y": the study's fit's sway damping."""
    import pipeline.models.fossen as fossen

    rows = store.load(root).sort_values(["trial", "t_ns"])
    test_name = params.features.test_trials[0]
    train, test = rows[rows["trial"] != test_name], rows[rows["trial"] == test_name]
    keep_last = fossen._last_own_damping
    out: dict = {}
    variants = {"study": (train, {}), "every term": (train, {"select": False}), "own damping kept": (train, {}),
                "fitted on the test trial": (test, {"select": False, "guard": False})}
    for name, (data, settings) in variants.items():
        if name == "own damping kept":
            fossen._last_own_damping = lambda term, current: term in fossen.DISSIPATIVE_TERMS
        try:
            est, scores = _fit_scores("fossen", params, vehicle, data, test, **settings)
        finally:
            fossen._last_own_damping = keep_last
        out[name] = {"r2": scores, "terms": est.selected_terms_ if est.select else None}
        if name == "study":
            out["Y"] = {k: v for k, v in est.coefficients().items() if k.startswith("Y_") and "dot" not in k}
    return out


def one_seed(seed: int, duration_s: float, params: Params, inflow: bool, models: list[str] | None,
             cv: bool = True, oracle: list[str] | None = None, preset: str = "gentle", n_train: int = 2,
             loto: bool = False, fossen_diag: bool = False) -> dict:
    from stages import derive, differentiate, features, ingest, sync, train, tune

    vehicle = load_example_vehicle()
    truth = dataclasses.replace(load_truth(), inflow_loss=DAGON_INFLOW_LOSS) if inflow else load_truth()
    if models:
        params = params.model_copy(update={"coupled": params.coupled.model_copy(update={"models": models})})
    names = [f"s{k + 1}" for k in range(n_train + 1)]  # training trials s1 ... sN, the unseen test trial last
    test_name = names[-1]
    params = params.model_copy(update={"features": params.features.model_copy(update={"test_trials": [test_name]})})
    out: dict = {"seed": seed, "preset": preset, "n_train": n_train}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "data/raw").mkdir(parents=True)
        trials = {}
        first = PRESET_SEED_OFFSET[preset] + 100 * seed + 1
        # the test trial's regime differs from every training trial's
        family = family_trials(first, n_train) if preset == "family" else None
        for k, name in enumerate(names):
            sim_seed = first + k
            if family is not None:
                sim_seed, regime = family[k]
                out.setdefault("regimes", {})[name] = {
                    "sim_seed": sim_seed, "redrawn_from": first + k if sim_seed != first + k else None,
                    "regime": regime.describe(), **dataclasses.asdict(regime)}
            trial = generate_trial(vehicle, duration_s, seed=sim_seed,
                                   truth=truth, warmup_s=30.0, start_offset_s=1000.0 * k, preset=preset)
            write_trial(trial, "mcap", root / f"data/raw/{name}.mcap")
            trials[name] = trial
        t0 = time.perf_counter()
        for stage in (ingest, sync, differentiate, derive, features, tune, *([train] if cv else [])):
            result = stage.run(root, vehicle, params)
            if result.quarantined:
                print(f"seed {seed}: {stage.NAME} quarantined {result.quarantined}", file=sys.stderr)
        out["stages_s"] = time.perf_counter() - t0
        test = store.load(root, trials=test_name).sort_values("t_ns")
        rows = trials[test_name].truth.set_index("t_ns").loc[test["t_ns"].to_numpy()]
        a_true = rows[list(OUTPUTS)].to_numpy()
        dyn = Dynamics(vehicle, truth)
        eta = np.zeros((len(test), 6))
        eta[:, 3], eta[:, 4] = test["roll_rad"].to_numpy(), test["pitch_rad"].to_numpy()
        nu = test[list(NU)].to_numpy(float)
        n = test[[t.speed_signal for t in vehicle.thrusters]].to_numpy(float)
        ceiling = dyn.nu_dot(eta, nu, n)[:, [0, 1, 5]]
        out["ceiling"] = {o: r2(ceiling[:, j], a_true[:, j]) for j, o in enumerate(OUTPUTS)}
        out["targets"] = {o: r2(test[o].to_numpy(), a_true[:, j]) for j, o in enumerate(OUTPUTS)}
        out["models"] = {}
        if cv:
            fitted, intervals = {}, {}
            for path in sorted((root / "data/models/coupled").glob("*.joblib")):
                est, card = load_model(path)
                fitted[card["model"]] = (est, card["inputs"])
                intervals[card["model"]] = card["interval"]
                if card.get("residual_fold_check"):  # a gray box's second verdict: against its base on the folds
                    out.setdefault("residual_fold_check", {})[card["model"]] = card["residual_fold_check"]
            metrics = json.loads((root / "data/evaluation/coupled/metrics.json").read_text())
            out["failed"] = {m: v["failed"] for m, v in metrics.items() if isinstance(v, dict) and "failed" in v}
        else:
            fitted, out["failed"] = final_models(root, params, vehicle), {}
        hyper = json.loads((root / "data/models/coupled/hyperparameters.json").read_text())["hyperparameters"]
        out["residual"] = {m: {o: h.get("residual") for o, h in per_out.items()}  # a gray box's: kept or dropped
                           for m, per_out in hyper.items() if any("residual" in h for h in per_out.values())}
        out["intervals"] = {}
        for model, (est, cols) in sorted(fitted.items()):
            pred = est.predict(test[cols].to_numpy(float))
            out["models"][model] = {o: r2(pred[:, j], a_true[:, j]) for j, o in enumerate(OUTPUTS)}
            if cv:
                out["intervals"][model] = interval_shares(intervals[model], test, pred)
        if oracle:
            out["oracle"] = oracle_scores(root, params, oracle, test, a_true)
        if loto:
            out["loto"] = loto_scores(root, params, vehicle)
        if fossen_diag:
            out["fossen_fits"] = fossen_fits(root, params, vehicle)
    return out


def regime_line(reg: dict) -> str:
    redrawn = f", redrawn from {reg['redrawn_from']}" if reg.get("redrawn_from") is not None else ""
    return f"{reg['regime']} (simulator seed {reg['sim_seed']}{redrawn})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--preset", nargs="+", choices=PRESETS, default=["gentle", "hard"],
                    help="simulator presets (default: the gentle default and the hard one; 'family': a regime per "
                         "trial), each its own seeds")
    ap.add_argument("--duration", type=float, default=480.0)
    ap.add_argument("--train-trials", type=int, default=2,
                    help="training trials s1 ... sN (default 2); the unseen test trial is s(N+1)")
    ap.add_argument("--params", type=Path, default=None,
                    help="a params file (default: none, the code's defaults; the test trial is always the last)")
    ap.add_argument("--models", nargs="+", default=None)
    ap.add_argument("--no-inflow", action="store_true",
                    help="no inflow loss (the truth's linear and cubic damping stay outside the explicit families)")
    ap.add_argument("--json", type=Path, default=None, help="also write the per-seed results here")
    ap.add_argument("--max-samples", type=int, default=None,
                    help="coupled.max_samples for this run (the tuning subsample; default: the params')")
    ap.add_argument("--no-cv", action="store_true",
                    help="skip the train stage's CV folds: fit the final models as it does (same test scores)")
    ap.add_argument("--intervals", action="store_true",
                    help="also each model's 90 %% interval and its share of the test trial's targets inside")
    ap.add_argument("--oracle", nargs="+", default=None, choices=OUTPUTS, metavar="OUTPUT",
                    help="also the best WDSE-SVR search candidate per seed on the test truth (a bound; see above)")
    ap.add_argument("--loto", action="store_true",
                    help="also the explicit model a choice per output by held-out training trials takes (see above)")
    ap.add_argument("--fossen-fits", action="store_true",
                    help="also Fossen's model fitted four ways, scored on the test trial's targets (see above)")
    args = ap.parse_args()
    if args.intervals and args.no_cv:
        ap.error("--intervals needs the train stage's CV folds: drop --no-cv")
    if args.oracle and args.models and "wdse_svr" not in args.models:
        ap.error("--oracle bounds the WDSE-SVR: add wdse_svr to --models")
    params = Params.model_validate(yaml.safe_load(args.params.read_text()) or {} if args.params else {})
    if args.max_samples is not None:
        params = params.model_copy(update={"coupled": params.coupled.model_copy(
            update={"max_samples": args.max_samples})})
    for preset in args.preset:
        report(preset, args, params)


def report(preset: str, args: argparse.Namespace, params: Params) -> None:
    results = []
    for seed in args.seeds:
        res = one_seed(seed, args.duration, params, not args.no_inflow, args.models, cv=not args.no_cv,
                       oracle=args.oracle, preset=preset, n_train=args.train_trials, loto=args.loto,
                       fossen_diag=args.fossen_fits)
        results.append(res)
        print(f"seed {seed}: stages {res['stages_s']:.0f} s, ceiling "
              + ", ".join(f"{o} {v:.3f}" for o, v in res["ceiling"].items()), file=sys.stderr, flush=True)
        for name, reg in res.get("regimes", {}).items():
            print(f"seed {seed} {name}: {regime_line(reg)}", file=sys.stderr, flush=True)
    if args.json:
        args.json.with_name(f"{args.json.stem}_{preset}{args.json.suffix}").write_text(json.dumps(results, indent=2))
    models = sorted({m for r in results for m in r["models"]})
    print(f"\n{preset} preset: R² against the TRUE accelerations of the unseen trial s{args.train_trials + 1} "
          f"({args.train_trials} training trials, {args.duration:.0f}-s trials, "
          f"{'inflow loss on' if not args.no_inflow else 'no inflow loss, damping outside the explicit families'}, "
          f"seeds {args.seeds}, coupled.max_samples {params.coupled.max_samples})")
    print("| model | " + " | ".join(f"{o} mean" for o in OUTPUTS) + " | " + " | ".join(f"{o} worst" for o in OUTPUTS)
          + " |")
    print("| --- |" + " ---: |" * 6)
    rows = [("ceiling (true model at the estimated inputs)", [r["ceiling"] for r in results]),
            ("targets (differentiate's accelerations)", [r["targets"] for r in results])]
    rows += [(m, [r["models"][m] for r in results if m in r["models"]]) for m in models]
    for name, per_seed in rows:
        mean = [np.mean([p[o] for p in per_seed]) for o in OUTPUTS]
        worst = [np.min([p[o] for p in per_seed]) for o in OUTPUTS]
        print(f"| {name} | " + " | ".join(f"{v:.3f}" for v in mean + worst) + " |")
    print(f"\n{preset} preset: gap to the ceiling (ceiling R² - model R², same seed), mean / worst seed")
    print("| model | " + " | ".join(OUTPUTS) + " |")
    print("| --- |" + " ---: |" * 3)
    for m in models:
        per = [r for r in results if m in r["models"]]
        gaps = [[r["ceiling"][o] - r["models"][m][o] for r in per] for o in OUTPUTS]
        print(f"| {m} | " + " | ".join(f"{np.mean(g):.3f} / {np.max(g):.3f}" for g in gaps) + " |")
    print("ceiling per seed (a low one, where an unknown force drives the accelerations, makes its gaps say little): "
          + "; ".join(f"seed {r['seed']} " + " / ".join(f"{r['ceiling'][o]:.3f}" for o in OUTPUTS) for r in results))
    for r in results:  # the family preset: each trial's regime
        for name, reg in r.get("regimes", {}).items():
            print(f"seed {r['seed']} {name}{' (test)' if name == f's{args.train_trials + 1}' else ''}: "
                  f"{regime_line(reg)}")
    for r in results:  # a gray box's residual per output: kept or dropped, with the CV R² that decided
        for m, verdicts in (r.get("residual") or {}).items():
            print(f"seed {r['seed']} {m} residual: " + "; ".join(f"{o} {v}" for o, v in verdicts.items()))
        for m, verdicts in (r.get("residual_fold_check") or {}).items():
            print(f"seed {r['seed']} {m} against its base (CV folds, held-out trials): "
                  + "; ".join(f"{o} {verdicts[o]['verdict']}" for o in OUTPUTS if o in verdicts))
    if args.intervals:
        print(f"\n{preset} preset: share of the unseen trial's MEASURED targets inside each model's 90 % interval "
              "(the method: the wider of the blocked CV's and the held-out trials' quantiles, its spread growing "
              "with |prediction|; the blocked CV's one half-width; normalized by the target's SD: the alternative), "
              "mean / worst over seeds")
        kinds = ("inside", "inside_blocked", "inside_sd")
        print("| model | " + " | ".join(f"{o} {k}" for k in ("inside", "blocked", "normalized") for o in OUTPUTS)
              + " |")
        print("| --- |" + " ---: |" * 9)
        for m in models:
            per = [r["intervals"][m] for r in results if m in r.get("intervals", {})]
            cells = [f"{np.mean(v):.3f} / {np.min(v):.3f}" if None not in (v := [p[o][k] for p in per]) else "–"
                     for k in kinds for o in OUTPUTS]
            print(f"| {m} | " + " | ".join(cells) + " |")
        for k in ("inside", "inside_constant", "inside_blocked", "inside_trials", "inside_mean"):  # every cell
            v = [x for r in results for per in r.get("intervals", {}).values() for o in OUTPUTS
                 if (x := per[o][k]) is not None]
            print(f"{k}: {sum(0.85 <= x <= 0.95 for x in v)} of {len(v)} (seed, model, output) inside 85-95 %, "
                  f"{sum(x < 0.85 for x in v)} under, {sum(x > 0.95 for x in v)} over")
    if args.oracle:
        print("\nbest WDSE-SVR candidate of the search, chosen on the test truth (a bound, not a method); per seed")
        for o in args.oracle:
            per = [r["oracle"][o]["best"] for r in results]
            chosen = [r["models"]["wdse_svr"][o] for r in results]
            ceiling = [r["ceiling"][o] for r in results]
            print(f"{o}: best {np.round(per, 3).tolist()} (mean {np.mean(per):.3f}), chosen "
                  f"{np.round(chosen, 3).tolist()}, ceiling {np.round(ceiling, 3).tolist()} "
                  f"(mean {np.mean(ceiling):.3f})")
    if args.loto:
        print("\nexplicit model chosen per output by held-out training trials (mean R² on them) against the best "
              "explicit model on the test truth; per seed: chosen R², best R², ceiling")
        for r in results:
            cells = []
            for j, o in enumerate(OUTPUTS):
                held = {m: np.mean([s[j] for s in per]) for m, per in r["loto"].items()}
                pick = max(held, key=held.get)
                best = max(r["loto"], key=lambda m: r["models"][m][o])
                cells.append(f"{o} {pick} {r['models'][pick][o]:.3f} (held-out {held[pick]:.2f}), best {best} "
                             f"{r['models'][best][o]:.3f}, ceiling {r['ceiling'][o]:.3f}")
            print(f"seed {r['seed']}: " + "; ".join(cells))
    if args.fossen_fits:
        print("\nFossen's model fitted four ways, R² on the test trial's targets (u̇ / v̇ / ṙ); per seed")
        for r in results:
            fits = r["fossen_fits"]
            print(f"seed {r['seed']}: " + "; ".join(
                f"{name} " + " / ".join(f"{v:.3f}" for v in f["r2"]) + (f" ({len(f['terms'])} terms)" if f["terms"]
                                                                       else "")
                for name, f in fits.items() if name != "Y")
                  + "; the study's sway damping " + ", ".join(f"{k} {v:.1f}" for k, v in fits["Y"].items()))
    failed = {r["seed"]: r["failed"] for r in results if r["failed"]}
    if failed:
        print(f"\nfailed models: {failed}")


if __name__ == "__main__":
    main()
