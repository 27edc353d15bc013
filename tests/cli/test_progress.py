"""Progress from every long stage through the stage progress callback: search candidates, CV folds, rollouts."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from pipeline.config.params import CoupledParams
from pipeline.evaluate import cross_validate_blocked, split_blocks
from pipeline.models.decoupled import LinearQuadraticDamping
from pipeline.models.search import fast_search, grid_search
from pipeline.rollout import rollout_ragged
from pipeline.sim.synthetic import synthetic_frame
from pipeline.studies.coupled import evaluate_models, tune
from stages import common


class Recorder:
    """A progress callback with the stages.common signature; remembers every call."""

    def __init__(self) -> None:
        self.calls: list[tuple[int, int | None, str | None]] = []

    def __call__(self, done: Any, total: Any = None, desc: str | None = None) -> None:
        self.calls.append((int(done), None if total is None else int(total), desc))

    @property
    def done(self) -> list[int]:
        return [d for d, _, _ in self.calls]


def _xy(n: int = 120, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 4))
    return X, np.sin(X[:, 0]) + 0.5 * X[:, 1] + 0.05 * rng.normal(size=n)


def test_fast_search_reports_each_candidate_against_its_budget() -> None:
    X, y = _xy()
    rec = Recorder()
    res = fast_search("rbf_svr", X, y, n_folds=2, max_evals=8, gp_samples=40, progress=rec)
    assert len(rec.calls) == res.n_candidates and rec.done == sorted(rec.done)
    assert {t for _, t, _ in rec.calls} == {8} and rec.done[-1] == min(res.n_candidates, 8)
    assert all(desc.startswith("rbf_svr ") for _, _, desc in rec.calls)
    plain = fast_search("rbf_svr", X, y, n_folds=2, max_evals=8, gp_samples=40)
    assert plain.best_params == res.best_params  # reporting changes nothing


def test_grid_search_reports_each_candidate_in_order() -> None:
    X, y = _xy()
    grid = {"C": [0.1, 1.0, 10.0], "epsilon": [0.01, 0.1], "gamma": [0.1, 1.0]}
    rec = Recorder()
    res = grid_search("rbf_svr", X, y, grid=grid, n_folds=2, progress=rec)
    assert rec.done == list(range(1, 13)) and {t for _, t, _ in rec.calls} == {12}
    assert res.best_params == grid_search("rbf_svr", X, y, grid=grid, n_folds=2).best_params


def test_cross_validation_reports_each_fold() -> None:
    X, y = _xy()
    rec = Recorder()
    folds = cross_validate_blocked(LinearQuadraticDamping(), X[:, :1], y, n_folds=4, progress=rec)
    assert len(folds) == 4 and rec.calls == [(k, 4, f"fold {k}/4") for k in range(1, 5)]


@pytest.fixture(scope="module")
def frame() -> Any:
    return split_blocks(synthetic_frame(400, seed=1))


def test_tune_names_each_search_and_its_place(frame: Any) -> None:
    cp = CoupledParams(models=["rbf_svr", "two_weights_svr"], max_evals=4, tuning="split", tuning_folds=2)
    rec = Recorder()
    tune(frame["tuning"], cp, progress=rec)
    # one chain per output (RBF, then 2-weights warm-started from it), run in output order
    searches = [f"{m}/{o} ({k}/6)" for k, (o, m) in enumerate(
        [(o, m) for o in cp.outputs for m in cp.models], start=1)]
    seen = list(dict.fromkeys(desc.split(" ", 2)[0] + " " + desc.split(" ", 2)[1] for _, _, desc in rec.calls))
    assert seen == searches
    assert all(t == 4 for _, t, _ in rec.calls)


def test_evaluate_models_reports_folds_and_final_fits(frame: Any) -> None:
    cp = CoupledParams(models=["gertler_hagen", "mcfarland_whitcomb"], folds=3, tuning="split")
    rec = Recorder()
    evaluate_models(frame["train_test"], frame["test"], {}, cp, progress=rec)
    assert rec.done == list(range(1, 9))  # (3 folds + the final fit) x 2 models, in order
    assert {t for _, t, _ in rec.calls} == {8}
    assert [desc for _, _, desc in rec.calls][3:5] == ["gertler_hagen final fit", "mcfarland_whitcomb fold 1/3"]


def test_rollout_reports_its_steps() -> None:
    def decay(state: np.ndarray, u: np.ndarray) -> np.ndarray:
        return -state + u

    rec = Recorder()
    inputs = np.zeros((500, 1))
    out, div = rollout_ragged(decay, np.ones((2, 1)), inputs, np.array([0, 100]), np.array([500, 300]), 0.01,
                              progress=rec)
    assert rec.done == sorted(rec.done) and rec.calls[-1] == (500, 500, "rollout steps")
    assert 90 <= len(rec.calls) <= 102
    again, _ = rollout_ragged(decay, np.ones((2, 1)), inputs, np.array([0, 100]), np.array([500, 300]), 0.01)
    np.testing.assert_array_equal(out, again)


@pytest.mark.parametrize("stage", ["ingest", "tune", "train", "decoupled", "simulate"])
def test_every_long_stage_takes_the_progress_callback(stage: str) -> None:
    module = common.load_stage(stage)
    assert "progress" in common.accepted_kwargs(module.run, {"progress": None})


def test_decoupled_and_simulate_stages_report_through_the_runner(tmp_path: Any) -> None:
    from pipeline.config import Params
    from tests.studies.helpers import build_store

    params = Params(features={"test_trials": ["test"]},
                    decoupled={"models": ["ls", "krr"], "max_samples": 60, "curve_points": 2, "folds": 2},
                    simulate={"band_samples": 0, "outage_windows_s": [5.0]})
    vehicle, _ = build_store(tmp_path, {"a": ("all", 21, 15.0, True), "test": ("all", 22, 15.0, False)}, params)
    dec, sim = Recorder(), Recorder()
    common.run_stage("decoupled", tmp_path, vehicle, params, progress=dec)
    assert dec.calls[0][:2] == (0, 6) and dec.done[1:] == list(range(1, 7))
    assert {desc for _, _, desc in dec.calls[1:]} == {f"{d}/{m}" for d in "uvr" for m in ("ls", "krr")}
    common.run_stage("simulate", tmp_path, vehicle, params, progress=sim)
    assert sim.calls and sim.calls[-1][0] == sim.calls[-1][1]
    assert all(desc.startswith("trial test (1/1): krr, ls (1/1) rollout steps") for _, _, desc in sim.calls)
