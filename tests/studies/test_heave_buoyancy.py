"""The decoupled study on a heave DOF reports the vehicle's net buoyancy B - W with its SD (issue 34, item 3).

The known answer: the depth-hold trial of ``tests/estimation/test_heave_only.py`` (3 N buoyant, Z_w 5, Z_ww 20,
depth at 10 Hz with 2 mm of noise), through ingest .. features and the decoupled stage (``dofs: [w]``, ``ls``
with its default constant for w). With ``buoyancy_N: null`` derive takes nothing out of d_w, so the constant is all
of B - W; with the right buoyancy_N the constant is ~0 and B - W comes from the config; with a wrong one (1 N) the
constant makes up the difference. Each way the reported B - W is 3 N, Z_w and Z_ww are the truth's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.config import Params, load_vehicle
from pipeline.models.decoupled import LinearQuadraticDamping
from stages import decoupled as decoupled_stage
from stages import derive as derive_stage
from stages import differentiate as differentiate_stage
from stages import features as features_stage
from stages import ingest as ingest_stage
from stages import sync as sync_stage
from tests.estimation.test_heave_only import BUOYANCY_N, VEHICLE, WEIGHT_N, ZW, ZWW, write_trial

NET_N = BUOYANCY_N - WEIGHT_N  # 3 N


def heave_study(home: Path, buoyancy_N: float | None, decoupled: dict | None = None) -> dict:
    """metrics.json of the decoupled stage on the depth-hold trial, the vehicle's buoyancy_N as given."""
    doc = {**VEHICLE, "rigid_body": {**VEHICLE["rigid_body"], "buoyancy_N": buoyancy_N}}
    (home / "heaver.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    if not (home / "dives").exists():
        write_trial(home / "dives" / "hold01")
    vehicle = load_vehicle(home / "heaver.yaml")
    params = Params.model_validate({"decoupled": {"dofs": ["w"], "models": ["ls"], "n_jobs": 1, **(decoupled or {})}})
    root = home / f"runs_{buoyancy_N}_{sorted(decoupled or {})}"
    for stage, extra in ((ingest_stage, {"logs": [home / "dives" / "hold01"]}), (sync_stage, {}),
                         (differentiate_stage, {}), (derive_stage, {}), (features_stage, {}), (decoupled_stage, {})):
        result = stage.run(root, vehicle, params, **extra)
        assert not result.quarantined, (stage.NAME, result.quarantined)
    card = json.loads((decoupled_stage.models_dir(root) / "w_ls.card.json").read_text())
    metrics = json.loads((decoupled_stage.evaluation_dir(root) / "metrics.json").read_text())
    assert card.get("net_buoyancy") == metrics["results"]["w"]["ls"].get("net_buoyancy")  # the card says the same
    return {**metrics["results"]["w"]["ls"], "table": (decoupled_stage.evaluation_dir(root) / "table.md").read_text()}


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("heave_study")


@pytest.mark.parametrize("buoyancy_N", [None, BUOYANCY_N, WEIGHT_N + 1.0], ids=["null", "right", "1N"])
def test_heave_ls_reports_b_minus_w_with_its_sd_and_the_damping(home: Path, buoyancy_N: float | None) -> None:
    r = heave_study(home, buoyancy_N)
    configured = 0.0 if buoyancy_N is None else buoyancy_N - WEIGHT_N
    b = r["net_buoyancy"]
    assert b["configured_N"] == pytest.approx(configured, abs=1e-9)
    assert b["intercept_N"] == pytest.approx(NET_N - configured, abs=0.05)
    assert b["B_minus_W_N"] == pytest.approx(NET_N, abs=0.05)  # 2.998 +- 0.017 N here (seed 0)
    assert 0 < b["sd_N"] < 0.05 and abs(b["B_minus_W_N"] - NET_N) < 4 * b["sd_N"]
    assert r["learned"]["d_l"] == pytest.approx(ZW, rel=0.02)  # 5.035
    assert r["learned"]["d_q"] == pytest.approx(ZWW, rel=0.02)  # 19.96
    assert r["cv"]["test_r2_mean"] > 0.99
    assert "B − W" in r["table"] and f"{b['B_minus_W_N']:.3f}" in r["table"]


def test_without_the_constant_heave_is_papers_model_and_no_b_minus_w(home: Path) -> None:
    r = heave_study(home, None, {"intercept": []})
    assert "net_buoyancy" not in r and "intercept" not in r["learned"]
    assert r["cv"]["test_r2_mean"] < 0.98  # the 3 N left in d_w: paper 001's model cannot hold it


def test_ls_constant_and_its_sd_on_known_data() -> None:
    rng = np.random.default_rng(0)
    x = np.sin(np.linspace(0.0, 60.0, 3000))
    y = 3.0 + 5.0 * x + 20.0 * x * np.abs(x) + rng.normal(0.0, 0.1, x.size)
    m = LinearQuadraticDamping(fit_intercept=True).fit(x[:, None], y)
    np.testing.assert_allclose([*m.coef_, m.intercept_], [5.0, 20.0, 3.0], atol=0.02)
    assert m.intercept_sd_ == pytest.approx(0.1 / np.sqrt(x.size) * np.sqrt(np.linalg.inv(
        np.column_stack([x, x * np.abs(x), np.ones_like(x)]).T @ np.column_stack([x, x * np.abs(x), np.ones_like(x)])
        / x.size)[2, 2]), rel=0.15)
    assert LinearQuadraticDamping().fit(x[:, None], y).intercept_sd_ is None
