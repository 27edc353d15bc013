"""`import auvid`: the three documented lines load a run's models and predict; intervals, free runs, versions and
aliases of the registry, and the errors of load."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import auvid
from pipeline import physics, registry
from pipeline.rollout import segment_runs
from tests.cli.model_helpers import build_home, build_run

REPO = Path(__file__).resolve().parents[2]
NU, TAU, G = ["u_mps", "v_mps", "r_radps"], ["tau_u_N", "tau_v_N", "tau_r_Nm"], ["g_u_N", "g_v_N", "g_r_Nm"]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_run(tmp_path_factory.mktemp("api_run"))


@pytest.fixture(scope="module")
def test_rows(run: Path) -> pd.DataFrame:
    return pq.read_table(run / "data/derived/test.parquet").to_pandas().dropna(subset=NU + TAU + G)


def _three_lines(doc: str) -> str:
    blocks = re.findall(r"```python\n(.*?)```", (REPO / doc).read_text(), re.S)
    found = [b for b in blocks if "auvid.load(" in b]
    assert len(found) == 1, f"{doc}: one python block with auvid.load"
    return found[0]


def _expected_ls(run: Path, nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """M_k^-1 (tau - C(nu) nu - d(nu)) written out from the fitted coefficients and the vehicle's M."""
    models = auvid.load(run)
    vehicle = models["ls"].vehicle
    M = physics.mass_matrix(vehicle)
    idx = [0, 1, 5]
    nu6 = np.zeros((len(nu), 6))
    nu6[:, idx] = nu
    d = np.column_stack([np.ravel(models["ls"].estimators[k].coef_)[0] * nu[:, j]
                         + np.ravel(models["ls"].estimators[k].coef_)[1] * nu[:, j] * np.abs(nu[:, j])
                         for j, k in enumerate("uvr")])
    rhs = tau - physics.coriolis_force(M, nu6)[:, idx] - d
    return np.linalg.solve(M[np.ix_(idx, idx)], rhs.T).T


@pytest.mark.parametrize("doc", ["README.md", "docs/user-guide.md"])
def test_the_documented_three_lines_load_the_model_and_predict(doc: str, run: Path, test_rows: pd.DataFrame,
                                                               tmp_path: Path) -> None:
    code = _three_lines(doc)
    assert len(code.strip().splitlines()) == 3
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs/basin").symlink_to(run)
    nu, tau = test_rows[NU].to_numpy(), test_rows[TAU].to_numpy() - test_rows[G].to_numpy()
    scope = {"nu": nu, "tau": tau}
    here = Path.cwd()
    os.chdir(tmp_path)
    try:
        exec(compile(code, doc, "exec"), scope)  # noqa: S102 - the documented lines, literally
    finally:
        os.chdir(here)
    np.testing.assert_allclose(scope["nudot"], _expected_ls(run, nu, tau), rtol=1e-9, atol=1e-12)
    # and the model explains the measured accelerations (the trial is one it was not fitted on)
    acc = test_rows[["udot_mps2", "vdot_mps2", "rdot_radps2"]].to_numpy()
    r2 = 1 - ((scope["nudot"] - acc) ** 2).sum(0) / ((acc - acc.mean(0)) ** 2).sum(0)
    assert (r2 > 0.5).all(), r2


def test_gp_has_a_band_and_ls_has_none(run: Path, test_rows: pd.DataFrame) -> None:
    models = auvid.load(run)
    nu, tau = test_rows[NU].to_numpy(), test_rows[TAU].to_numpy() - test_rows[G].to_numpy()
    nudot, lo, hi = models["gp"].predict(nu, tau, interval=True)
    assert models["gp"].has_interval and (lo < nudot).all() and (nudot < hi).all()
    np.testing.assert_array_equal(nudot, models["gp"].predict(nu, tau))
    assert models["ls"].predict(nu, tau, interval=True)[1:] == (None, None) and models["ls"].interval_kind is None
    assert models["gp"].interval_kind == "2-sd band"
    assert models["coupled_rbf_svr"].inputs == ["n1_rpm", "n2_rpm"] and models["ls"].trials == ["a"]
    with pytest.raises(ValueError, match=r"tau \(n, 3\)"):
        models["ls"].predict(nu, tau[:, :2])


def test_a_coupled_model_gives_its_90_percent_interval(run: Path, test_rows: pd.DataFrame, tmp_path: Path) -> None:
    """A coupled model's band is the 90 % interval its card holds (the train stage writes it), by hand:
    p +- q (c_0 + c_1 |p|) per output, wider where the model predicts a larger acceleration; a card without one
    (the run's stand-in model) gives none."""
    import json
    import shutil

    assert auvid.load(run)["coupled_rbf_svr"].predict(np.zeros((1, 3)), np.zeros((1, 2)), interval=True)[1:] \
        == (None, None)
    copy = tmp_path / "run"
    shutil.copytree(run, copy, symlinks=True)
    path = copy / "data/models/coupled/rbf_svr.card.json"
    card = json.loads(path.read_text())
    spreads = {"udot_mps2": [0.01, 0.2], "vdot_mps2": [0.02, 0.0], "rdot_radps2": [0.005, 0.5]}
    card["interval"] = {o: {"level": 0.9, "scale": "prediction", "spread": c, "half_width_scaled": 1.5,
                            "half_width": 0.03} for o, c in spreads.items()}
    path.write_text(json.dumps(card))
    model = auvid.load(copy)["coupled_rbf_svr"]
    nu, tau = test_rows[NU].to_numpy(), test_rows[model.inputs].to_numpy()
    nudot, lo, hi = model.predict(nu, tau, interval=True)
    assert model.interval_kind == "90 % interval"
    np.testing.assert_array_equal(nudot, model.predict(nu, tau))
    for j, out in enumerate(model.outputs):
        c0, c1 = spreads[out]
        half = 1.5 * (c0 + c1 * np.abs(nudot[:, j]))
        np.testing.assert_allclose(hi[:, j] - nudot[:, j], half, rtol=1e-12)
        np.testing.assert_allclose(nudot[:, j] - lo[:, j], half, rtol=1e-12)


@pytest.mark.parametrize("name", ["ls", "gp", "coupled_rbf_svr"])
def test_simulate_is_the_simulate_stage_s_free_run(name: str, run: Path) -> None:
    """The API's free run over the test trial's first valid run equals the stage's (tables there: < 1 % RMS)."""
    free = pq.read_table(run / "data/simulation/test/free_run.parquet").to_pandas()
    rows = pq.read_table(run / "data/derived/test.parquet").to_pandas().set_index("t_ns").loc[free["t_ns"]]
    seg = rows["segment"].to_numpy() if "segment" in rows else None
    a, b = segment_runs(free["t_ns"].to_numpy(), seg, float(np.median(np.diff(free["t_ns"]))) * 1e-9)[0]
    model = auvid.load(run)[name]
    inputs = rows[TAU].to_numpy() - rows[G].to_numpy() if model.kind == "decoupled" else rows[model.inputs].to_numpy()
    t_s = (free["t_ns"].to_numpy()[a:b] - free["t_ns"].iloc[a]) * 1e-9
    t_s = t_s[0] + np.arange(t_s.size) * np.median(np.diff(t_s))
    ours = model.simulate(free[NU].to_numpy()[a], inputs[a:b], t_s)
    stage = free[[f"{name}/{c}" for c in NU]].to_numpy()[a:b]
    rms = np.sqrt(np.mean((ours - stage) ** 2, axis=0)) / np.sqrt(np.mean(stage**2, axis=0))
    assert (rms < 0.01).all(), rms


def test_load_errors_name_the_place(run: Path, tmp_path: Path) -> None:
    with pytest.raises(auvid.LoadError, match="no such run directory"):
        auvid.load(tmp_path / "nowhere")
    with pytest.raises(auvid.LoadError, match="not a run directory"):
        auvid.load(tmp_path)
    with pytest.raises(auvid.LoadError, match="retraining home"):
        auvid.load(run, version="v0001")
    with pytest.raises(KeyError, match="available"):
        auvid.load(run)["svr"]


def test_registry_versions_and_a_per_output_champion(run: Path, tmp_path: Path) -> None:
    home = build_home(run, tmp_path / "home")
    assert auvid.load(home).version == "v0001" and auvid.load(home, version="v0002").version == "v0002"
    assert auvid.load(home / "models/v0002").version == "v0002"
    with pytest.raises(auvid.LoadError, match="unknown model version 'v0009'"):
        auvid.load(home, version="v0009")
    with pytest.raises(registry.UnknownVersion, match="no alias 'champion'"):
        auvid.load(home, alias="champion")

    registry.promote_model(home, "v0001", "ls")  # every output of ls
    registry.promote_model(home, "v0002", "coupled_rbf_svr", ["vdot_mps2"])  # one output, from another version
    data = registry.load(home)
    assert data["current"] == "v0001"  # the version is untouched
    assert data["aliases"]["champion"] == {"udot_mps2": {"version": "v0001", "model": "ls"},
                                           "vdot_mps2": {"version": "v0002", "model": "coupled_rbf_svr"},
                                           "rdot_radps2": {"version": "v0001", "model": "ls"}}
    champion = auvid.load(home, alias="champion")
    assert {o: (m.name, m.version) for o, m in champion.champion.items()} == {
        "udot_mps2": ("ls", "v0001"), "vdot_mps2": ("coupled_rbf_svr", "v0002"), "rdot_radps2": ("ls", "v0001")}
    assert sorted(champion) == ["coupled_rbf_svr", "ls"]
    events = registry.version(data, "v0002")["events"]
    assert events[-1]["action"] == "promote_model" and events[-1]["outputs"] == ["vdot_mps2"]
    with pytest.raises(registry.UnknownVersion, match="its models: .*'gp'"):
        registry.promote_model(home, "v0001", "svr")
    with pytest.raises(registry.UnknownVersion, match=r"not \['wdot_mps2'\]"):
        registry.promote_model(home, "v0001", "ls", ["wdot_mps2"])
    assert registry.load(home)["aliases"] == data["aliases"]  # refused promotions change nothing
