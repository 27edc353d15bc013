"""One failing model does not lose the others: the train and decoupled stages write each model as it finishes,
name the failed one (tables, metrics, quarantine list) and exit with 1.

The failure is forced (a model whose fit raises, as TLS did on a vehicle without sway actuation), so this test
does not depend on how tolerant the models themselves are of a degenerate column."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline import store
from pipeline.config import Params, Vehicle
from pipeline.errors import ModelError
from pipeline.models import explicit
from pipeline.sim import load_example_vehicle
from pipeline.sim.synthetic import SyntheticPlant, synthetic_frame, synthetic_trial
from stages import decoupled as decoupled_stage
from stages import train as train_stage
from stages.common import EXIT_QUARANTINED

ZERO_SWAY = "TLS: regressor column(s) [7] are identically zero"


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return load_example_vehicle()


def _store(root: Path, vehicle: Vehicle, frames: dict[str, pd.DataFrame], params: Params) -> None:
    """Write the frames as feature-store partitions: absent fixed columns zero, columns not in the schema dropped."""
    for trial, frame in frames.items():
        frame = frame[[c for c in frame.columns if c in ("t_ns", "segment") or store._column_type(c) is not None]]
        fill = {n: 0.0 for n, _ in store.FIXED_COLUMNS if n != "split" and n not in frame.columns}
        store.write_trial(root, vehicle.name, trial, frame.assign(**fill), params.features, {})


def _raise_zero_sway(self, X, y):  # noqa: ANN001, ANN202 - the signature of the patched fit
    raise ModelError(ZERO_SWAY)


def test_train_keeps_the_models_that_finished_and_names_the_one_that_failed(tmp_path: Path, vehicle: Vehicle,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    params = Params(features={"test_trials": ["b"]},
                    coupled={"models": ["gertler_hagen", "mcfarland_whitcomb"], "folds": 3})
    frames = {t: synthetic_frame(400, seed=s, trial=t, rate_hz=5.0) for t, s in (("a", 1), ("b", 2))}
    _store(tmp_path, vehicle, frames, params)
    stale = tmp_path / "data/models/coupled/mcfarland_whitcomb.joblib"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"an earlier run's model")
    monkeypatch.setattr(explicit.McFarlandWhitcomb, "fit", _raise_zero_sway)

    result = train_stage.run(tmp_path, vehicle, params)

    assert result.exit_code == EXIT_QUARANTINED
    [entry] = result.quarantined
    assert entry["model"] == "mcfarland_whitcomb" and ZERO_SWAY in entry["reason"]
    assert "mcfarland_whitcomb" in entry["reason"] and entry["file"].endswith("mcfarland_whitcomb.joblib")
    models = tmp_path / "data/models/coupled"
    assert (models / "gertler_hagen.joblib").exists() and (models / "gertler_hagen.card.json").exists()
    assert not stale.exists()  # the simulate stage must not pick up a model this run could not fit
    ev = tmp_path / "data/evaluation/coupled"
    metrics = json.loads((ev / "metrics.json").read_text())
    assert set(metrics["gertler_hagen"]) == {"udot_mps2", "vdot_mps2", "rdot_radps2"}
    assert ZERO_SWAY in metrics["mcfarland_whitcomb"]["failed"]
    table = (ev / "table3.md").read_text()
    assert "| Gertler-Hagen |" in table and "Failed, not in the table: McFarland-Whitcomb" in table
    assert "failed" in json.loads((ev / "table3.json").read_text())["mcfarland_whitcomb"]


def test_train_writes_each_model_as_it_finishes(tmp_path: Path, vehicle: Vehicle,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A study stopped by a later model (here: interrupted) still leaves the finished model's files.

    The interrupt comes once the first model is written, however many workers run the study's tasks at once:
    in a pool the second model's fits may start before the first model's last fit ends. The first model's final
    fit is one task (Fossen's; Gertler-Hagen's bootstrap runs in tasks of its own, after the second model's folds
    have started)."""
    params = Params(features={"test_trials": ["b"]},
                    coupled={"models": ["fossen", "mcfarland_whitcomb"], "folds": 3})
    _store(tmp_path, vehicle, {t: synthetic_frame(400, seed=s, trial=t, rate_hz=5.0)
                               for t, s in (("a", 1), ("b", 2))}, params)
    finished = tmp_path / "data/models/coupled/fossen.card.json"

    def interrupted(self, X, y):  # noqa: ANN001, ANN202
        deadline = time.monotonic() + 60.0
        while not finished.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        raise KeyboardInterrupt  # never swallowed as a model failure

    monkeypatch.setattr(explicit.McFarlandWhitcomb, "fit", interrupted)
    with pytest.raises(KeyboardInterrupt):
        train_stage.run(tmp_path, vehicle, params)
    assert (tmp_path / "data/models/coupled/fossen.joblib").exists()
    metrics = json.loads((tmp_path / "data/evaluation/coupled/metrics.json").read_text())
    assert set(metrics) == {"fossen"}


def test_train_fails_when_every_model_fails(tmp_path: Path, vehicle: Vehicle, monkeypatch: pytest.MonkeyPatch) -> None:
    params = Params(features={"test_trials": ["b"]}, coupled={"models": ["mcfarland_whitcomb"], "folds": 3})
    _store(tmp_path, vehicle, {t: synthetic_frame(300, seed=s, trial=t, rate_hz=5.0)
                               for t, s in (("a", 1), ("b", 2))}, params)
    monkeypatch.setattr(explicit.McFarlandWhitcomb, "fit", _raise_zero_sway)
    with pytest.raises(ModelError, match="every coupled model failed: mcfarland_whitcomb"):
        train_stage.run(tmp_path, vehicle, params)


def test_decoupled_keeps_the_models_that_finished(tmp_path: Path, vehicle: Vehicle,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    from pipeline.studies import decoupled as decoupled_study

    params = Params(features={"test_trials": ["b"]},
                    decoupled={"models": ["ls", "svr"], "dofs": ["u", "v"], "max_samples": 150, "folds": 3,
                               "curve_points": 2})
    plant = SyntheticPlant()
    frames = {t: synthetic_trial(plant, duration_s=40.0, rate_hz=10.0, seed=s) for t, s in (("a", 1), ("b", 2))}
    _store(tmp_path, vehicle, frames, params)
    real = decoupled_study.tune

    def tune(name: str, *args, **kw):  # noqa: ANN002, ANN003, ANN202
        if name == "svr":
            raise np.linalg.LinAlgError("singular matrix")
        return real(name, *args, **kw)

    monkeypatch.setattr(decoupled_study, "tune", tune)
    result = decoupled_stage.run(tmp_path, vehicle, params)
    assert result.exit_code == EXIT_QUARANTINED
    assert sorted((e["dof"], e["model"]) for e in result.quarantined) == [("u", "svr"), ("v", "svr")]
    assert all("singular matrix" in e["reason"] for e in result.quarantined)
    for dof in ("u", "v"):
        assert (tmp_path / f"data/models/decoupled/{dof}_ls.joblib").exists()
        assert not (tmp_path / f"data/models/decoupled/{dof}_svr.joblib").exists()
    metrics = json.loads((tmp_path / "data/evaluation/decoupled/metrics.json").read_text())["results"]
    assert "cv" in metrics["u"]["ls"] and "singular matrix" in metrics["u"]["svr"]["failed"]
    assert "Failed, not in the table: v/svr" in (tmp_path / "data/evaluation/decoupled/table.md").read_text()
