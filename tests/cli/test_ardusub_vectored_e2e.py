"""A BlueROV2 in ArduSub's vectored frame, from mavros bags to a 4-DOF damping model (issue 34, item 3).

``pipeline.sim.ardusub_vectored.vectored_trial`` flies a 60-s manual-mode trial: the pilot's forward, lateral, yaw and
throttle (RC override) mixed by the frame's known factors into six integer servo outputs; surge, sway, heave and
yaw with Wu's BlueROV2 damping, B - W = 2 N. Two ROS 2 bags without message definitions are written from it:
``rov01`` with the servo outputs (``/mavros/rc/out``), ``manual01`` with only the override. The user's steps are
the guide's (section 8.3): ``auvid init`` (the servo outputs mapped, or the override with a ``mixing`` block whose
frame is a TODO), the TODOs filled, ``auvid run --to features``, ``auvid decoupled`` on u, v, w, r.

Known answers: each mapping's generalized forces (the feature store's ``tau_*``) are the simulator's true tau = B T
(servo outputs: to rounding; mixed inputs: within the 1-us quantisation of the servo outputs), and the decoupled
LS model recovers the simulator's damping and B - W.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import yaml

from pipeline.cli import main
from pipeline.config import todo_markers
from pipeline.sim.ardusub import thrust_N, thrust_table_csv
from pipeline.sim.ardusub_vectored import DIRECTIONS, FACTORS, POSITIONS, VectoredTruth, allocation, vectored_trial
from pipeline.sim.writers import MAVROS_TYPES, mavros_msgdef, write_trial
from pipeline.tableio import read_parquet

TRUTH = VectoredTruth()
DURATION_S = 60.0
DOFS = ("u", "v", "w", "r")
TAU = {"u": "tau_u_N", "v": "tau_v_N", "w": "tau_w_N", "r": "tau_r_Nm"}
TABLE = {"table": "thrust_table.csv", "table_pwm_column": "PWM (µs)", "table_thrust_column": "Force (Kg f)",
         "table_thrust_unit": "kgf"}
FILLED: dict[str, Any] = {
    "rigid_body.mass_kg": TRUTH.mass_kg, "rigid_body.inertia_kgm2": np.diag([0.16, 0.16, TRUTH.izz_kgm2]).tolist(),
    "rigid_body.cg_m": [0.0, 0.0, 0.0], "rigid_body.cb_m": [0.0, 0.0, 0.0], "rigid_body.buoyancy_N": None,
    "added_mass": np.diag([*TRUTH.added_kg[:3], 0.12, 0.12, TRUTH.added_kg[3]]).tolist(),
    **{f"thrusters.{i}.{key}": value for i in range(6) for key, value in (
        ("position_m", POSITIONS[i].tolist()), ("direction", DIRECTIONS[i].round(4).tolist()), ("thrust", TABLE))},
}
PARAMS = {"decoupled": {"dofs": list(DOFS), "models": ["ls"], "n_jobs": 1}}


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    home = tmp_path_factory.mktemp("vectored")
    trial = vectored_trial(DURATION_S, seed=0)
    write_trial(trial, "ros2-sqlite3", home / "dives" / "rov01", definitions=False)
    write_trial(trial, "ros2-sqlite3", home / "dives" / "manual01", definitions=False,
                topics=tuple(s.topic for s in trial.streams.values() if s.topic != "/mavros/rc/out"))
    for msgtype in MAVROS_TYPES:  # the user's mavros_msgs tree (a mavros checkout)
        pkg, _, name = msgtype.split("/")
        (home / "msgs" / pkg / "msg").mkdir(parents=True, exist_ok=True)
        (home / "msgs" / pkg / "msg" / f"{name}.msg").write_text(mavros_msgdef(msgtype), encoding="utf-8")
    (home / "thrust_table.csv").write_text(thrust_table_csv(), encoding="utf-8")
    trial.truth.to_parquet(home / "truth.parquet")
    return home


def fill(doc: dict[str, Any], values: dict[str, Any]) -> None:
    for key, value in values.items():
        *path, last = key.split(".")
        node: Any = doc
        for part in path:
            node = node[int(part)] if isinstance(node, list) else node[part]
        node[int(last) if isinstance(node, list) else last] = value


def init_and_run(home: Path, bag: str, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """``auvid init`` on the bag, its TODOs filled, ``auvid run --to features``: the starter and the features."""
    monkeypatch.chdir(home)
    assert main(["init", f"dives/{bag}", "--msgs", "msgs", "--name", "bluerov2", "-o", f"{bag}.yaml"]) == 0
    text = Path(f"{bag}.yaml").read_text(encoding="utf-8")
    doc = yaml.safe_load(text)
    values = dict(FILLED)
    if bag == "manual01":
        values["streams.rc_override.mixing.frame"] = "ardusub_vectored"
    assert sorted(k for k, _ in todo_markers(doc)) == sorted(values)  # every TODO init wrote, and nothing else
    fill(doc, values)
    Path(f"{bag}.yaml").write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    Path("params.yaml").write_text(yaml.safe_dump(PARAMS), encoding="utf-8")
    common = ["--root", f"runs/{bag}", "--vehicle", f"{bag}.yaml", "--params", "params.yaml", "-q"]
    assert main(["run", *common, "--to", "features", f"dives/{bag}"]) == 0
    part = next(Path(f"runs/{bag}/data/features").rglob("*.parquet"))
    return {"doc": doc, "text": text, "common": common, "features": read_parquet(part)[0].to_pandas()}


@pytest.fixture(scope="module")
def runs(home: Path) -> dict[str, dict[str, Any]]:
    with pytest.MonkeyPatch.context() as mp:
        return {bag: init_and_run(home, bag, mp) for bag in ("rov01", "manual01")}


def true_tau_at(home: Path, t_ns: np.ndarray) -> pd.DataFrame:
    """The simulator's tau at each time (the last integration step at or before it: tau is held between steps)."""
    truth = pd.read_parquet(home / "truth.parquet")
    rows = np.searchsorted(truth["t_ns"].to_numpy(), t_ns, side="right") - 1
    return truth.iloc[rows].reset_index(drop=True)


def test_init_maps_servo_outputs_where_logged_else_the_override_mixed(runs: dict[str, dict[str, Any]]) -> None:
    servo, manual = runs["rov01"]["doc"], runs["manual01"]["doc"]
    assert servo["streams"]["rc_out"]["topic"] == "/mavros/rc/out" and "rc_override" not in servo["streams"]
    mixing = manual["streams"]["rc_override"]["mixing"]
    assert mixing["frame"] == "ardusub_vectored" and mixing["outputs"] == [f"pwm{k}_s" for k in range(1, 7)]
    shown = [line.split(": ", 1)[1] for line in runs["manual01"]["text"].splitlines() if "#   motor " in line]
    assert [json.loads(row) for row in shown] == FACTORS.tolist()  # the preset's matrix, shown beside the TODO
    for doc in (servo, manual):
        assert doc["sensors"]["depth"] == "depth_m" and doc["sensors"]["velocity"]["axes"] == "flu"
        assert doc["sensors"]["attitude"]["convention"] == "flu_enu"


@pytest.mark.parametrize("bag", ["rov01", "manual01"], ids=["servo_outputs", "override_mixed"])
def test_each_mapping_gives_the_true_generalized_forces(home: Path, runs: dict[str, dict[str, Any]],
                                                        bag: str) -> None:
    features = runs[bag]["features"]
    truth = true_tau_at(home, features["t_ns"].to_numpy())
    got = np.column_stack([features[TAU[d]] for d in DOFS])
    want = truth[[f"tau_{d}" for d in DOFS]].to_numpy()
    assert len(features) > 0.9 * DURATION_S * 20  # the 20-Hz grid, nearly every row kept
    assert np.ptp(want, axis=0).min() > 3.0  # every DOF driven (tau_r spans > 3 N m)
    if bag == "rov01":  # the servo outputs are what the motors got: tau exactly
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    else:  # mixed from the inputs: the servo outputs' rounding, at most 0.5 us on each motor, is all that differs
        pwm = truth[[f"pwm{i}_us" for i in range(1, 7)]].to_numpy()
        slope = np.abs(thrust_N(pwm + 0.5) - thrust_N(pwm - 0.5))  # N per us around each motor's PWM
        bound = (np.abs(allocation()) @ slope.T).T[:, [0, 1, 2, 5]] * 0.5 + 1e-9
        assert np.all(np.abs(got - want) <= bound)
        assert np.abs(got - want).max() > 0  # not the servo outputs in disguise


def test_the_decoupled_study_recovers_the_damping_and_b_minus_w(home: Path, runs: dict[str, dict[str, Any]],
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(home)
    assert main(["decoupled", *runs["rov01"]["common"]]) == 0
    metrics = json.loads(Path("runs/rov01/data/evaluation/decoupled/metrics.json").read_text())["results"]
    # seeds 0-2 (60 s): linear terms within 0.1-6.6 %, quadratic 0.1-2.6 %, B - W 1.99-2.02 N, CV R² >= 0.985
    for i, dof in enumerate(DOFS):
        ls = metrics[dof]["ls"]
        assert ls["learned"]["d_l"] == pytest.approx(TRUTH.linear[i], rel=0.1), dof
        assert ls["learned"]["d_q"] == pytest.approx(TRUTH.quadratic[i], rel=0.05), dof
        assert ls["cv"]["test_r2_mean"] > 0.97, dof
    assert metrics["w"]["ls"]["net_buoyancy"]["B_minus_W_N"] == pytest.approx(TRUTH.net_buoyancy_N, abs=0.05)
