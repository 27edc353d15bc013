"""Acceptance of issue 5 on the project's simulator: single-DOF trials through the real stages, the decoupled study,
then free runs, horizons and DVL-outage bridging on a test trial with every thruster excited."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline import store
from pipeline.config import Params
from pipeline.sim import StreamSpec, true_damping
from pipeline.studies.decoupled import dof_columns
from stages import decoupled as decoupled_stage
from stages import simulate as simulate_stage
from tests.studies.helpers import build_store

DOF_INDEX = {"u": 0, "v": 1, "r": 5}
EXCITED_BY = {"u": "surge", "v": "sway", "r": "yaw"}
#: The GP's calibration below was measured (bench/decoupled_coverage.py) on Gaussian-derivative targets from the
#: simulator's former plain 4 Hz DVL; these tests keep those conditions. On the kalman method's targets from the
#: realistic DVL the decoupled GP is not yet re-calibrated (u: GP curve error 0.40 N vs LS 0.23; r coverage 0.63).
PLAIN_DVL = dict(dvl=StreamSpec(4.0, 0.020, -0.05, 0.005), dvl_ping_interval_s=None, dvl_outlier_rate=0.0,
                 dvl_scale_error=0.0, dvl_misalignment_rpy_deg=(0.0, 0.0, 0.0), dvl_averaging_s=0.0,
                 dvl_lock_loss_fraction=0.0, dropout_bursts_per_min=1.0)
PARAMS = Params(
    differentiate={"method": "gaussian", "sigma_s": 0.25},
    features={"test_trials": ["test"]},
    decoupled={"models": ["ls", "gp"], "max_samples": 400, "gp_max_samples": 400, "curve_points": 2,
               "folds": 3, "trials": {d: [t] for d, t in EXCITED_BY.items()}},
    simulate={"band_samples": 0, "outage_windows_s": [10.0, 30.0], "models": ["ls", "gp"]},
)


@pytest.fixture(scope="module")
def study_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("sim_store")
    # long enough for the cubic terms of surge and yaw to show (the first 20 % of each is the tuning block)
    specs = {"surge": ("surge", 11, 120.0, True), "sway": ("sway", 12, 45.0, True), "yaw": ("yaw", 13, 100.0, True),
             "test": ("all", 14, 80.0, False)}
    vehicle, _ = build_store(root, specs, PARAMS, sensors=PLAIN_DVL)
    decoupled_stage.run(root, vehicle, PARAMS)
    simulate_stage.run(root, vehicle, PARAMS)
    return root


def curve_errors(root: Path, dof: str) -> tuple[dict[str, float], float, dict[str, object]]:
    """Per model: mean |learned - true| over the curve grid (2-98 % of the velocities); the noise (std of the
    damping target about the truth) in the DOF's trial; the curves."""
    x_col, y_col = dof_columns(dof)
    data = store.load(root, trials=EXCITED_BY[dof], split="train_test").dropna(subset=[x_col, y_col])
    j = DOF_INDEX[dof]

    def truth(x: np.ndarray) -> np.ndarray:
        nu = np.zeros((len(x), 6))
        nu[:, j] = x
        return true_damping(nu)[:, j]

    noise = float(np.std(data[y_col].to_numpy() - truth(data[x_col].to_numpy())))
    curves = json.loads((root / "data/evaluation/decoupled/curves.json").read_text())[dof]
    lo, hi = np.quantile(data[x_col], [0.02, 0.98])
    errors = {}
    for model, c in curves.items():
        nu = np.asarray(c["nu"])
        keep = (nu >= lo) & (nu <= hi)
        errors[model] = float(np.mean(np.abs(np.asarray(c["d"])[keep] - truth(nu[keep]))))
    curves["_truth"] = {"keep": ((np.asarray(curves["gp"]["nu"]) >= lo) & (np.asarray(curves["gp"]["nu"]) <= hi)),
                        "d": truth(np.asarray(curves["gp"]["nu"]))}
    return errors, noise, curves


@pytest.mark.parametrize("dof", ["u", "v", "r"])
def test_learned_curves_match_the_truth_within_the_noise(study_root: Path, dof: str) -> None:
    errors, noise, _ = curve_errors(study_root, dof)
    assert all(e < noise for e in errors.values()), (errors, noise)


def test_a_kernel_model_beats_ls_where_the_truth_is_cubic(study_root: Path) -> None:
    # surge and yaw have cubic terms (8 u^3, 4 r^3): the GP's curve is closer to the truth than LS's (SVR too, at
    # 3x the test's time: u 0.11 vs LS 0.26 N, r 0.010 vs 0.027 N*m; sway's 20 v^3 is too small at |v| < 0.5 m/s)
    for dof in ("u", "r"):
        errors, noise, _ = curve_errors(study_root, dof)
        assert errors["gp"] < 0.7 * errors["ls"], (dof, errors)


def gp_coverage(root: Path, dof: str) -> float:
    """Fraction of the curve grid (2-98 % of the DOF's velocities) where the GP's 2-sigma band covers the truth."""
    _, _, curves = curve_errors(root, dof)
    keep, truth = curves["_truth"]["keep"], curves["_truth"]["d"]
    mean, sd = np.asarray(curves["gp"]["d"])[keep], np.asarray(curves["gp"]["sd"])[keep]
    return float(np.mean(np.abs(mean - truth[keep]) <= 2 * sd))


@pytest.mark.parametrize("dof", ["u", "v", "r"])
def test_gp_band_covers_the_truth(study_root: Path, dof: str) -> None:
    # The GP sees (nu, nu|nu|) (DampingGP(warp="signed_square")). Over 8 seed sets of these trials
    # (python bench/decoupled_coverage.py --configs default corrected) the 2-sigma coverage of the truth averaged
    # u 0.95, v 0.97, r 0.88; with the paper's plain RBF on nu, u 0.84, v 0.97, r 0.83, the band missing around
    # nu = 0 on every seed. What r still misses is the plain Gaussian derivative's bias around r = 0
    # (differentiate.gaussian_degree=4 removes it: u 0.97, v 0.98, r 0.96; not the default, see docs/models.md).
    coverage = gp_coverage(study_root, dof)
    assert 0.75 <= coverage <= 1.0, (dof, coverage)


def test_gp_band_is_calibrated_on_average(study_root: Path) -> None:
    coverage = [gp_coverage(study_root, dof) for dof in ("u", "v", "r")]
    assert np.mean(coverage) >= 0.85, coverage


def test_bridging_beats_hold_last_and_horizon_errors_grow(study_root: Path) -> None:
    metrics = json.loads((study_root / "data/simulation/metrics.json").read_text())["test"]
    err = {(r["window_s"], r["model"]): r["mean_error_m"] for r in metrics["bridging"]}
    best = min(v for (w, m), v in err.items() if w == 30.0 and m != "hold_last" and v is not None)
    assert best < 0.3 * err[(30.0, "hold_last")], err
    assert all(r["status"] == "ok" for r in metrics["free_run"])
    for name, horizons in metrics["horizons"].items():
        for dof in ("u", "v", "r"):
            assert horizons["10"]["mae_end"][dof] >= horizons["1"]["mae_end"][dof], (name, dof, horizons)
