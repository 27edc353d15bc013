"""A small run directory with fitted models (decoupled ls and gp, one carded coupled model) and its free runs,
for the model API, `auvid predict`, the Fossen export and per-model promotion."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow.parquet as pq
from sklearn.linear_model import LinearRegression

from pipeline import registry
from pipeline.config import load_params
from pipeline.models.card import save_model
from pipeline.sim.trial import example_vehicle_path
from stages import decoupled as decoupled_stage
from stages import simulate as simulate_stage
from tests.studies.helpers import build_store

PARAMS_YAML = """\
features: {test_trials: [test]}
decoupled: {models: [ls, gp], max_samples: 60, gp_max_samples: 60, curve_points: 2, folds: 2}
coupled: {models: [rbf_svr]}
simulate: {band_samples: 4, outage_windows_s: [5.0]}
"""
COUPLED_IN = ["u_mps", "v_mps", "r_radps", "n1_rpm", "n2_rpm"]
COUPLED_OUT = ["udot_mps2", "vdot_mps2", "rdot_radps2"]


def build_run(root: Path) -> Path:
    """Trials ``a`` (fit) and ``test`` (15 s each) through ingest ... decoupled, a linear coupled model carded as
    ``rbf_svr`` (a stand-in: any estimator with predict), then simulate; vehicle.yaml and params.yaml beside."""
    (root / "params.yaml").write_text(PARAMS_YAML)
    (root / "vehicle.yaml").write_text(example_vehicle_path().read_text(encoding="utf-8"))
    params = load_params(root / "params.yaml")
    vehicle, _ = build_store(root, {"a": ("all", 21, 15.0, True), "test": ("all", 22, 15.0, False)}, params)
    decoupled_stage.run(root, vehicle, params)
    derived = pq.read_table(root / "data/derived/a.parquet").to_pandas().dropna(subset=COUPLED_IN + COUPLED_OUT)
    lin = LinearRegression().fit(derived[COUPLED_IN].to_numpy(), derived[COUPLED_OUT].to_numpy())
    save_model(lin, root / "data/models/coupled/rbf_svr.joblib", {"inputs": COUPLED_IN, "outputs": COUPLED_OUT,
                                                                  "trained_on": {"trials": ["a"]}})
    simulate_stage.run(root, vehicle, params)
    return root


def build_home(run: Path, home: Path, versions: tuple[str, ...] = ("v0001", "v0002")) -> Path:
    """A retraining home whose versions all hold ``run``'s models; the first is current."""
    home.mkdir(parents=True)
    shutil.copy(run / "vehicle.yaml", home / "vehicle.yaml")
    data = registry.empty()
    for k, name in enumerate(versions):
        target = home / "models" / name
        shutil.copytree(run / "data/models", target / "data/models")
        shutil.copy(run / "params.yaml", target / "params.yaml")
        data["versions"].append({"version": name, "status": "promoted" if k == 0 else "rejected",
                                 "parent": versions[k - 1] if k else None, "holdout_score": 0.5})
    data["current"] = versions[0]
    registry.save(home, data)
    return home
