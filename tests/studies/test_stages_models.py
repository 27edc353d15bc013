"""Coupled study (paper 000) end to end on the project's simulator: features store -> tune -> train -> simulate.

Three DAGON trials from ``pipeline.sim`` (coupled true damping, DAGON's sensor noise and rates) go through the real
stages (sync, differentiate, derive, features), then ``stages.tune`` and ``stages.train``; the third trial is the
test trial that neither tuning nor CV sees.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline import store
from pipeline.config import Params, Vehicle
from pipeline.config.params import CoupledParams
from pipeline.errors import ModelError
from pipeline.models.card import load_model
from pipeline.sim import load_example_vehicle
from pipeline.studies.coupled import GRAYBOX_MODELS, evaluate_models
from stages import train as train_stage
from stages import tune as tune_stage
from tests.studies.helpers import coupled_store

TRIALS = {"s1": 11, "s2": 12, "s3": 13}  # trial -> simulator seed; s3 is the test trial
DURATION_S = 40.0  # the plumbing tests: outputs, cards, rerun, guard, simulate (the acceptance has its own store)
COUPLED = {"folds": 3, "max_evals": 4, "max_samples": 200}


def study_params(**coupled) -> Params:
    return Params(features={"test_trials": ["s3"]}, coupled={**COUPLED, **coupled})


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return load_example_vehicle()


@pytest.fixture(scope="module")
def run_root(tmp_path_factory, vehicle: Vehicle) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("coupled")
    params = study_params()
    coupled_store(root, TRIALS, DURATION_S, params)
    t0 = time.perf_counter()
    tuned = tune_stage.run(root, vehicle, params)
    trained = train_stage.run(root, vehicle, params)
    return root, {"tune": tuned, "train": trained, "seconds": time.perf_counter() - t0}


MODELS = tuple(CoupledParams().models)  # the defaults: the three SVRs, the explicit models, one gray box
(GRAYBOX,) = [m for m in MODELS if m in GRAYBOX_MODELS]


def test_outputs_tables_figure_and_model_cards(run_root) -> None:
    root, res = run_root
    ev, md = root / "data/evaluation/coupled", root / "data/models/coupled"
    for name in ("table2.md", "table2.json", "table3.md", "table3.json", "fold_scores.json", "metrics.json",
                 "search_trace.json"):
        assert (ev / name).stat().st_size > 0, name
    assert not (ev / "fold_test_r2.png").exists()  # Fig. 4 is the report's, drawn from fold_scores.json
    assert "WDSE-SVR" in (ev / "table3.md").read_text() and "gamma_T_th3_N" in (ev / "table2.md").read_text()
    hyper = json.loads((md / "hyperparameters.json").read_text())
    assert hyper["n_tuning_rows"] > 0 and set(hyper["hyperparameters"]) == {*MODELS[:3], GRAYBOX}
    # nested (the default): searched on the train_test block, the rows the final models are fitted on
    n_train_test = len(store.load(root, split="train_test", columns=["t_ns"]))
    assert hyper["tuned_on"] == "train_test" and hyper["n_tuning_rows"] == n_train_test
    for model in MODELS:
        est, card = load_model(md / f"{model}.joblib")  # checks the pickle's sha256 against its card
        assert card["model"] == model and card["outputs"] == ["udot_mps2", "vdot_mps2", "rdot_radps2"]
        lineage = card["data_lineage"]
        assert sorted(e["file"].split("/")[-2] for e in lineage) == [f"trial={t}" for t in sorted(TRIALS)]
        assert all(len(e["sha256"]) == 64 for e in lineage)
        assert card["trained_on"]["trials"] == ["s1", "s2"] and card["scores"]["final_check_trials"] == ["s3"]
        assert card["versions"]["scikit-learn"] and hasattr(est, "predict")
    # the gray box's card says per output whether its residual was kept by the tuned record, and then how it fared
    # against its own base on the CV's folds and on each held-out training trial, which decide by default
    # (coupled.residual_fold_check: trials); the fit does as both say; Table III's JSON and markdown say it too
    gray = hyper["hyperparameters"][GRAYBOX]
    _, card = load_model(md / f"{GRAYBOX}.joblib")
    assert card["residual"] == {o: gray[o]["residual"] for o in gray}
    folds = card["residual_fold_check"]
    assert set(folds) == set(card["outputs"]) and all(
        " over 3 folds; gray box − base, test R² " in rec["verdict"] and " over 2 held-out trials" in rec["verdict"]
        and len(rec["differences"]) == 3 for rec in folds.values()), folds
    kept = [k for k, o in enumerate(card["outputs"]) if card["residual"][o].startswith("kept")
            and folds[o]["verdict"].startswith("kept")]
    assert load_model(md / f"{GRAYBOX}.joblib")[0].kept_outputs_ == kept
    assert json.loads((ev / "table3.json").read_text())[GRAYBOX]["residual"] == folds
    assert "against its own base (CV folds, held-out trials): udot_mps2: " in (ev / "table3.md").read_text()
    # the fits without a trial keep the tune stage's residuals, so an output without one is the base's exactly
    # there (a difference of 0), and one with it differs
    for out in card["outputs"]:
        across = folds[out]["trial_differences"]
        tuned = card["residual"][out].startswith("kept")
        assert len(across) == 2 and (all(d != 0.0 for d in across) if tuned else across == [0.0, 0.0]), across
    metrics = res["train"].summary["metrics"]
    assert set(metrics) == set(MODELS)
    assert all(np.isfinite(v["final_r2"]) for m in metrics.values() for v in m.values())


def test_rerun_gives_identical_metrics(run_root, vehicle: Vehicle) -> None:
    root, _ = run_root
    path = root / "data/evaluation/coupled/metrics.json"
    before = path.read_bytes()
    train_stage.run(root, vehicle, study_params())
    assert path.read_bytes() == before


def test_leakage_guard_fires_on_a_bad_split(run_root) -> None:
    root, _ = run_root
    cp = study_params().coupled
    hyper = json.loads((root / "data/models/coupled/hyperparameters.json").read_text())["hyperparameters"]
    cols = ["t_ns", "u_mps", "v_mps", "r_radps", "T_th1_N", "T_th2_N", "T_th3_N", "tau_u_N", "tau_v_N", "tau_r_Nm",
            "udot_mps2", "vdot_mps2", "rdot_radps2"]
    tt = store.load(root, split="train_test", columns=cols)
    tuning = store.load(root, split="tuning", columns=["t_ns"])
    with pytest.raises(ModelError, match="leakage"):  # "test" rows that are training rows
        evaluate_models(tt, tt.iloc[200:260], hyper, cp)
    with pytest.raises(ModelError, match="tuning"):  # tuning block overlapping the CV data
        evaluate_models(tt, tt.iloc[:0], hyper, cp, tuning_keys=tt[["trial", "t_ns"]].iloc[300:320])
    evaluate_models(tt, tt.iloc[:0], {}, cp.model_copy(update={"models": ["gertler_hagen"]}),
                    tuning_keys=tuning[["trial", "t_ns"]])  # the real split passes


def test_simulate_stage_rolls_out_trained_coupled_models(run_root, vehicle: Vehicle, tmp_path: Path) -> None:
    import shutil

    from stages import simulate as simulate_stage

    root, _ = run_root
    shutil.copytree(root / "data/features", tmp_path / "data/features")
    (tmp_path / "data/models/coupled").mkdir(parents=True)
    for name in ("wdse_svr.joblib", "wdse_svr.card.json", "mcfarland_whitcomb.card.json", "hyperparameters.json"):
        shutil.copy(root / "data/models/coupled" / name, tmp_path / "data/models/coupled" / name)
    with pytest.raises(ModelError, match="sha256|No such|not"):  # a card whose pickle is missing is refused
        simulate_stage.coupled_models(tmp_path, ["u", "v", "r"])
    (tmp_path / "data/models/coupled/mcfarland_whitcomb.card.json").unlink()
    found = simulate_stage.coupled_models(tmp_path, ["u", "v", "r"])
    assert set(found) == {"coupled_wdse_svr"} and found["coupled_wdse_svr"][1] == ["T_th1_N", "T_th2_N", "T_th3_N"]
    params = study_params().model_copy(update={"simulate": study_params().simulate.model_copy(
        update={"horizons_s": [1.0], "outage_windows_s": [5.0]})})
    result = simulate_stage.run(tmp_path, vehicle, params)
    assert set(result.summary["status"]) == {"s3/coupled_wdse_svr"}
    assert (tmp_path / "data/simulation/s3/free_run.json").exists()


#: Issue 4's acceptance setup (docs/models.md): three 300-s DAGON trials from pipeline.sim with coupled damping and the
#: propellers' thrust loss to inflow (DAGON_INFLOW_LOSS, which DAGON's static K n|n| curve in the vehicle config,
#: hence the store's tau, does not know), each cut from a run already in motion (30 s warm-up). Searched as by
#: default (nested) on a 600-row subsample of s1 and s2's train_test block, 5 blocked folds and 20 candidates per
#: model and output, and again inside each of 2 blocked CV folds; final check on s3. About 4 min on 2 cores: the
#: slowest test of the suite, and always run, since it is
#: the acceptance criterion of the coupled-model study.
ACCEPTANCE_TRIALS = {"s1": 11, "s2": 12, "s3": 13}
ACCEPTANCE_DURATION_S, ACCEPTANCE_WARMUP_S = 300.0, 30.0
ACCEPTANCE_COUPLED = {"folds": 2, "tuning_folds": 5, "max_evals": 20, "max_samples": 600, "tuning": "nested",
                      "models": ["rbf_svr", "two_weights_svr", "wdse_svr", "gertler_hagen", "mcfarland_whitcomb"]}


def test_acceptance_wdse_beats_rbf_and_explicit_on_test_trial(tmp_path: Path) -> None:
    import dataclasses

    from pipeline.sim import DAGON_INFLOW_LOSS, load_truth

    params = Params(features={"test_trials": ["s3"], "tuning_fraction": 0.2}, coupled=ACCEPTANCE_COUPLED)
    truth = dataclasses.replace(load_truth(), inflow_loss=DAGON_INFLOW_LOSS)
    vehicle = coupled_store(tmp_path, ACCEPTANCE_TRIALS, ACCEPTANCE_DURATION_S, params, truth=truth,
                            warmup_s=ACCEPTANCE_WARMUP_S)
    tune_stage.run(tmp_path, vehicle, params)
    metrics = train_stage.run(tmp_path, vehicle, params).summary["metrics"]
    final = {m: {o: metrics[m][o]["final_r2"] for o in ("udot_mps2", "vdot_mps2", "rdot_radps2")}
             for m in ("rbf_svr", "wdse_svr", "gertler_hagen", "mcfarland_whitcomb")}
    # The default protocol (coupled.tuning: nested, C scaled to the rows fitted, 5 search folds). Under the papers'
    # split protocol this seed ranked nothing (WDSE 0.80 / 0.81 / 0.91 against RBF 0.79 / 0.85 / 0.91: the tuning
    # block's CV does not pick hyperparameters that transfer, docs/models.md). Nested, on this seed, with the
    # thrusters' thrust as the SVRs' inputs (2026-11-26): WDSE 0.971 / 0.932 / 0.985, 2-weights 0.968 / 0.930 /
    # 0.981, RBF 0.959 / 0.913 / 0.965 (with their speeds, 2026-11-25: WDSE 0.948 / 0.929 / 0.971, RBF 0.947 / 0.853 /
    # 0.931), McFarland-Whitcomb 0.951 / 0.891 / 0.852, Gertler-Hagen 0.664 / 0.874 / 0.803 (their inputs are tau, so
    # unchanged). What must hold: WDSE at least RBF's skill on every output (within seed
    # noise), above both explicit models where their structure misses the truth (v_dot, r_dot), and real skill.
    for out in ("udot_mps2", "vdot_mps2", "rdot_radps2"):
        assert final["wdse_svr"][out] > final["rbf_svr"][out] - 0.01, (out, final)
        if out != "udot_mps2":
            assert final["wdse_svr"][out] > max(final["gertler_hagen"][out], final["mcfarland_whitcomb"][out]), \
                (out, final)
        assert max(f[out] for f in final.values()) > 0.9, (out, final)


def test_train_refuses_hyperparameters_of_the_other_tuning_mode(run_root, vehicle: Vehicle, tmp_path: Path) -> None:
    """Hyperparameters searched under coupled.tuning=nested are not silently reused by a run that says split."""
    import shutil

    root, _ = run_root
    shutil.copytree(root / "data/features", tmp_path / "data/features")
    shutil.copytree(root / "data/models/coupled", tmp_path / "data/models/coupled")
    with pytest.raises(ModelError, match="tuning='nested'.*run stages.tune again"):
        train_stage.run(tmp_path, vehicle, study_params(tuning="split"))


def test_explicit_refine_refines_from_wtls_and_says_so_on_the_card(run_root, vehicle: Vehicle, tmp_path: Path) -> None:
    """coupled.explicit_refine: the explicit models' coefficients move from the WTLS fit only where that lowers the
    free-run error over refine_horizon_s windows at the store's grid step, and the card records it."""
    import shutil

    root, _ = run_root
    shutil.copytree(root / "data/features", tmp_path / "data/features")
    params = study_params(models=["gertler_hagen", "mcfarland_whitcomb"], explicit_refine=True, refine_horizon_s=1.0)
    train_stage.run(tmp_path, vehicle, params)
    explicit = ("gertler_hagen", "mcfarland_whitcomb")
    plain = {m: load_model(root / f"data/models/coupled/{m}.joblib")[1] for m in explicit}
    for model in explicit:
        est, card = load_model(tmp_path / f"data/models/coupled/{model}.joblib")
        ref = card["refinement"]
        assert est.dt_s == pytest.approx(1.0 / params.sync.rate_hz) and ref["horizon_s"] == 1.0  # the sync grid
        cost = ref["free_run_cost"]
        assert cost["refined"] <= cost["wtls"]
        changed = card["coefficients"] != plain[model]["coefficients"]
        assert changed == ref["refined"] == (cost["refined"] < cost["wtls"])
    assert any(load_model(tmp_path / f"data/models/coupled/{m}.joblib")[1]["refinement"]["refined"]
               for m in explicit)


def test_graybox_residual_is_tuned_on_the_base_it_is_fitted_with(run_root, vehicle: Vehicle, tmp_path: Path,
                                                                 monkeypatch) -> None:
    """The tune stage weights the gray box's explicit base by the smoother's SDs as train does: the residual its
    WDSE search sees is the residual of the base the trained model carries (an unweighted base in tune gave other
    residuals, so the hyperparameters were searched on a target the model never learns)."""
    import shutil

    import pipeline.studies.tasks as tasks
    from pipeline.studies.coupled import build_model, model_inputs, noise_std_from
    from pipeline.vocabulary import NOISE_STD_COLUMNS

    root, _ = run_root
    shutil.copytree(root / "data/features", tmp_path / "data/features")
    params = study_params(models=["graybox"], search="fast")
    seen: list[np.ndarray] = []
    real = tasks.search_rounds

    def recording(model, X, y, *a, **kw):  # a search in rounds (pipeline.rounds), recorded as it starts
        seen.append(np.array(y))
        return (yield from real(model, X, y, *a, **kw))

    monkeypatch.setattr(tasks, "search_rounds", recording)
    monkeypatch.setenv("AUVID_JOBS", "1")  # inline: the chains one after the other, each search starting in order
    tune_stage.run(tmp_path, vehicle, params)
    cp = params.coupled
    tt = store.load(tmp_path, split="train_test")
    assert all(c in tt.columns for c in NOISE_STD_COLUMNS) and noise_std_from(tt) is not None
    sub = tt.iloc[np.unique(np.linspace(0, len(tt) - 1, cp.max_samples).round().astype(int))]
    base = build_model("graybox", {o: {"gammas": [1.0] * 6, "C": 1.0, "epsilon": 0.1} for o in cp.outputs}, cp,
                       train=tt).base
    base.fit(tt[model_inputs("mcfarland_whitcomb", cp)].to_numpy(float), tt[cp.outputs].to_numpy(float))
    resid = sub[cp.outputs].to_numpy(float) - base.predict(sub[model_inputs("mcfarland_whitcomb", cp)].to_numpy(float))
    # per output: the residual's RBF -> 2-weights -> WDSE chain, three searches on the same residual
    assert len(seen) == 3 * len(cp.outputs)
    for k in range(len(cp.outputs)):
        for y in seen[3 * k:3 * k + 3]:
            np.testing.assert_allclose(y, resid[:, k], rtol=1e-9, atol=1e-12)
