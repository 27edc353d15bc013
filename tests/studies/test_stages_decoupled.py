"""The decoupled and simulate stage shells on a small store from pipeline.sim: outputs, reruns, divergence."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.config import Params, Vehicle
from pipeline.models.card import save_model
from pipeline.models.decoupled import LinearQuadraticDamping
from stages import decoupled as decoupled_stage
from stages import simulate as simulate_stage
from tests.studies.helpers import build_store

PARAMS = Params(
    features={"test_trials": ["test"]},
    decoupled={"models": ["ls", "gp"], "max_samples": 100, "gp_max_samples": 100, "curve_points": 2, "folds": 3},
    simulate={"band_samples": 4, "outage_windows_s": [10.0]},
)
EVALUATION = ["metrics.json", "timings.json", "curves.json", "table.md", "learning_curves.png", "timings.png",
              "damping.png"]
SIMULATION = ["free_run.json", "free_run.png", "horizons.json", "bridging.json", "bridging.md", "bridging.png"]


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Vehicle]:
    root = tmp_path_factory.mktemp("stage_store")
    vehicle, _ = build_store(root, {"a": ("all", 21, 40.0, True), "test": ("all", 22, 40.0, False)}, PARAMS)
    decoupled_stage.run(root, vehicle, PARAMS)
    simulate_stage.run(root, vehicle, PARAMS)
    return root, vehicle


def test_outputs_exist(built: tuple[Path, Vehicle]) -> None:
    root, _ = built
    for dof in ("u", "v", "r"):
        for model in ("ls", "gp"):
            card = json.loads((root / f"data/models/decoupled/{dof}_{model}.card.json").read_text())
            assert (root / f"data/models/decoupled/{dof}_{model}.joblib").exists()
            assert card["dof"] == dof and card["model"] == model and card["lineage"]["trials"] == ["a"]
            # the 90 % interval and its coverage on the unseen trial travel with the model
            assert card["interval"]["level"] == 0.9 and card["interval"]["half_width"] > 0
            assert card["test"]["trials"] == ["test"] and 0 <= card["test"]["interval_coverage"] <= 1
            assert ("band_coverage" in card["test"]) == (model == "gp")
    for name in EVALUATION:
        assert (root / "data/evaluation/decoupled" / name).stat().st_size > 0, name
    table = (root / "data/evaluation/decoupled/table.md").read_text()
    assert sum(line.startswith("|") for line in table.splitlines()) == 2 + 6 and "test trial(s) test" in table
    for name in SIMULATION:
        assert (root / "data/simulation/test" / name).stat().st_size > 0, name
    metrics = json.loads((root / "data/simulation/metrics.json").read_text())["test"]
    assert {r["model"] for r in metrics["free_run"]} == {"ls", "gp"}
    assert all(r["status"] == "ok" for r in metrics["free_run"])
    assert "band_coverage" in next(r for r in metrics["free_run"] if r["model"] == "gp")
    assert set(metrics["horizons"]["gp"]) == {"1", "5", "10"}
    assert {r["model"] for r in metrics["bridging"]} == {"hold_last", "ls", "gp"}
    assert "| 10 | hold_last |" in (root / "data/simulation/test/bridging.md").read_text()


def test_rerun_gives_identical_metrics(built: tuple[Path, Vehicle]) -> None:
    root, vehicle = built
    files = [root / "data/evaluation/decoupled/metrics.json", root / "data/evaluation/decoupled/curves.json",
             root / "data/simulation/metrics.json"]
    before = [p.read_bytes() for p in files]
    decoupled_stage.run(root, vehicle, PARAMS)
    simulate_stage.run(root, vehicle, PARAMS)
    assert [p.read_bytes() for p in files] == before
    timings = json.loads((root / "data/evaluation/decoupled/timings.json").read_text())
    assert set(timings) == {f"{d}/{m}" for d in ("u", "v", "r") for m in ("ls", "gp")}  # kept apart from metrics


def test_a_diverging_model_is_reported_with_its_status(built: tuple[Path, Vehicle], tmp_path: Path) -> None:
    src, vehicle = built
    root = tmp_path / "copy"
    shutil.copytree(src, root)
    negative = LinearQuadraticDamping().fit(np.c_[[-1.0, 1.0]], [40.0, -40.0])  # negative damping: unstable
    for dof in ("u", "v", "r"):
        save_model(negative, root / f"data/models/decoupled/{dof}_neg.joblib", {"dof": dof, "model": "neg"})
    result = simulate_stage.run(root, vehicle, PARAMS)
    assert result.summary["status"] == {"test/gp": "ok", "test/ls": "ok", "test/neg": "diverged"}
    metrics = json.loads((root / "data/simulation/metrics.json").read_text())["test"]
    neg = next(r for r in metrics["free_run"] if r["model"] == "neg")
    assert neg["diverged_at_s"] is not None and neg["diverged_at_s"] > 0
    assert metrics["horizons"]["neg"]["10"]["n_diverged"] > 0
    bridge = next(r for r in metrics["bridging"] if r["model"] == "neg")
    assert bridge["n_diverged"] > 0
    assert (root / "data/simulation/test/free_run.png").stat().st_size > 0
    assert "NaN" not in (root / "data/simulation/metrics.json").read_text()
