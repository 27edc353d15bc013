"""A simulated ArduSub depth-hold dive, from a ROS 2 bag with mavros topics to a heave model (issue 34, item 3).

The bag is written by the project's simulator (``pipeline.sim.ardusub.heave_trial``, ``pipeline.sim.write_trial``):
the servo outputs ``/mavros/rc/out`` (RCOut, the vertical motors 5 and 6 under the depth controller) and
``/mavros/global_position/rel_alt`` (Float64, metres up, 3 mm of noise), no attitude. The user's steps are the
user guide's (section 8.2): ``auvid init`` drafts the config, the TODOs are filled with the BlueROV2 walkthrough's
constants and the sheet the simulator wrote (buoyancy left unknown: ``null``), and ``auvid run`` goes from the bag
to the decoupled heave model. The known answer: the simulator's Z_w, Z_ww and B - W. The whole ``auvid run`` (no
``--to``) on the same dive: the coupled stages and the free runs skip, saying why, and the report shows B - W.
"""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.cli import main
from pipeline.config import todo_markers
from pipeline.sim.ardusub import HeaveTruth, heave_trial, thrust_table_csv
from pipeline.sim.writers import write_trial
from pipeline.skips import SKIPPED
from tests.cli.test_dvc import expanded_stages
from tests.cli.test_rov_e2e import DIRECTIONS, POSITIONS

TRUTH = HeaveTruth()
DURATION_S = 60.0
#: the filled-in TODOs: the BlueROV2 walkthrough's constants; buoyancy unknown to the user
FILLED = {
    "rigid_body.mass_kg": TRUTH.mass_kg, "rigid_body.inertia_kgm2": np.diag([0.16] * 3).tolist(),
    "rigid_body.cg_m": [0.0, 0.0, 0.0], "rigid_body.cb_m": [0.0, 0.0, 0.0], "rigid_body.buoyancy_N": None,
    "added_mass": np.diag([5.5, 12.7, TRUTH.added_mass_kg, 0.12, 0.12, 0.12]).tolist(),
}
TABLE = {"table": "thrust_table.csv", "table_pwm_column": "PWM (µs)", "table_thrust_column": "Force (Kg f)",
         "table_thrust_unit": "kgf"}
PARAMS = {"decoupled": {"dofs": ["w"], "models": ["ls", "krr"], "n_jobs": 1}}


def fill(doc: dict, key: str, value: object) -> None:
    *path, last = key.split(".")
    node = doc
    for part in path:
        node = node[int(part)] if isinstance(node, list) else node[part]
    node[int(last) if isinstance(node, list) else last] = value


def filled_todos() -> dict[str, object]:
    """Every TODO ``auvid init`` writes for the dive, with the walkthrough's values."""
    values = {**FILLED}
    for i in range(6):
        values |= {f"thrusters.{i}.position_m": POSITIONS[i].tolist(),
                   f"thrusters.{i}.direction": DIRECTIONS[i].tolist(), f"thrusters.{i}.thrust": TABLE}
    return values


def configure(name: str) -> None:
    """``auvid init`` on the dive into ``<name>.yaml``, its TODOs filled, and params.yaml (in the current dir)."""
    assert main(["init", "dives/hold01", "--name", "bluerov2", "-o", f"{name}.yaml"]) == 0
    doc = yaml.safe_load(Path(f"{name}.yaml").read_text(encoding="utf-8"))
    for key, value in filled_todos().items():
        fill(doc, key, value)
    Path(f"{name}.yaml").write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    Path("params.yaml").write_text(yaml.safe_dump(PARAMS), encoding="utf-8")


@pytest.fixture(scope="module")
def dive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    home = tmp_path_factory.mktemp("ardusub")
    write_trial(heave_trial(DURATION_S, seed=0), "ros2-sqlite3", home / "dives" / "hold01")
    write_trial(heave_trial(DURATION_S, seed=1), "ros2-sqlite3", home / "more" / "hold02")  # an unseen dive
    (home / "thrust_table.csv").write_text(thrust_table_csv(), encoding="utf-8")
    return home


def test_init_then_run_gives_heave_damping_and_b_minus_w(dive: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(dive)
    assert main(["init", "dives/hold01", "--name", "bluerov2", "-o", "bluerov2.yaml"]) == 0
    doc = yaml.safe_load(Path("bluerov2.yaml").read_text(encoding="utf-8"))
    assert doc["sensors"]["position"] == {"signals": ["depth_m"], "components": ["z"]}  # heave only, level
    assert "attitude" not in doc["sensors"]
    values = filled_todos()
    todos = [k for k, _ in todo_markers(doc)]
    assert sorted(todos) == sorted(values)  # every TODO init wrote, and nothing else
    for key, value in values.items():
        fill(doc, key, value)
    Path("bluerov2.yaml").write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    Path("params.yaml").write_text(yaml.safe_dump(PARAMS), encoding="utf-8")
    capsys.readouterr()

    common = ["--root", "runs/hold", "--vehicle", "bluerov2.yaml", "--params", "params.yaml", "-q"]
    assert main(["run", *common, "--to", "features", "dives/hold01"]) == 0
    assert main(["decoupled", *common]) == 0

    metrics = json.loads(Path("runs/hold/data/evaluation/decoupled/metrics.json").read_text())["results"]["w"]
    ls = metrics["ls"]
    b = ls["net_buoyancy"]
    assert b["configured_N"] == 0.0  # buoyancy_N: null
    # seeds 0-2: B - W 2.034 / 2.056 / 2.063 N (SD 0.044-0.065) for 2 N; Z_w 6.44 / 6.19 / 6.24 for 6; Z_ww 23.3 /
    # 23.5 / 23.2 for 25; CV R² ls 0.976 / 0.954 / 0.940, krr 0.977 / 0.947 / 0.934
    assert b["B_minus_W_N"] == pytest.approx(TRUTH.net_buoyancy_N, abs=0.1)
    assert abs(b["B_minus_W_N"] - TRUTH.net_buoyancy_N) < 3 * b["sd_N"]
    assert ls["learned"]["d_l"] == pytest.approx(TRUTH.z_w, rel=0.1)
    assert ls["learned"]["d_q"] == pytest.approx(TRUTH.z_ww, rel=0.1)
    assert ls["cv"]["test_r2_mean"] > 0.9 and metrics["krr"]["cv"]["test_r2_mean"] > 0.9
    card = json.loads(Path("runs/hold/data/models/decoupled/w_ls.card.json").read_text())
    assert card["net_buoyancy"] == b


def _text(report: Path) -> str:
    """The report's words, without markup, entities resolved."""
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", report.read_text(encoding="utf-8"))))


def test_the_whole_run_skips_the_coupled_stages_saying_why_and_reports_b_minus_w(
        dive: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``auvid run`` without ``--to`` on the heave-only dive: exit 0; tune and train skip (the vehicle has no u/v/r
    DOFs), simulate skips (no unseen trial: one dive), each leaving a marker in the outputs dvc.yaml declares; the
    report shows B - W with its SD and says why the coupled study and the free runs are missing; a rerun writes the
    same markers."""
    monkeypatch.chdir(dive)
    configure("full")
    capsys.readouterr()
    root = Path("runs/full")
    args = ["run", "--root", str(root), "--vehicle", "full.yaml", "--params", "params.yaml", "-q", "dives/hold01"]
    assert main(args) == 0
    line = capsys.readouterr().out
    why = "the vehicle 'bluerov2' has no u/v/r DOFs (its sensors measure w only), and the coupled study needs them"
    assert f"tune, train skipped: {why}" in line
    assert "simulate skipped: no unseen trial (features.test_trials is empty)" in line

    coupled = [root / "data/models/coupled", root / "data/evaluation/coupled"]
    for directory in coupled:
        assert [p.name for p in directory.iterdir()] == [SKIPPED]
        marker = json.loads((directory / SKIPPED).read_text(encoding="utf-8"))
        assert marker["stages"] == ["tune", "train"] and marker["skipped"].startswith(why)
    sim = json.loads((root / "data/simulation" / SKIPPED).read_text(encoding="utf-8"))
    assert sim["stages"] == ["simulate"] and sim["skipped"].startswith("no unseen trial")
    for name, full, stage in expanded_stages():  # what DVC checks after each stage: its declared outputs exist
        for out in stage.get("outs") or [] if name != "example" else []:  # example: DVC's data/raw, not auvid's
            assert (root / out).exists(), f"{full}: out {out} missing"

    metrics = json.loads((root / "data/evaluation/decoupled/metrics.json").read_text())["results"]["w"]
    b = metrics["ls"]["net_buoyancy"]
    text = _text(root / "reports/report.html")
    shown = re.findall(r"B − W = (-?[0-9.]+) ± ([0-9.]+) N \(1 SD\)", text)
    assert len(shown) == 2  # in the summary box and in the damping study's section
    assert {shown[0]} == set(shown)
    value, sd = map(float, shown[0])
    assert value == pytest.approx(TRUTH.net_buoyancy_N, abs=0.1)
    assert (value, sd) == (round(b["B_minus_W_N"], 3), round(b["sd_N"], 3))
    assert f"The coupled study (paper 000) was skipped (stages tune, train): {why}" in text
    assert "The free runs were skipped (stage simulate): no unseen trial" in text
    assert "No extrapolation diagnostics: the coupled study was skipped" in text

    outs = [*coupled, root / "data/simulation"]
    before = {p: p.read_bytes() for d in outs for p in d.iterdir()}
    # what an earlier run left (models of a vehicle config with u, v, r; a free run) is not this run's
    for stale in (root / "data/models/coupled/rbf_svr.joblib", root / "data/simulation/old/free_run.json"):
        stale.parent.mkdir(exist_ok=True)
        stale.write_text("{}")
    assert main(args) == 0
    assert {p: p.read_bytes() for d in outs for p in d.iterdir()} == before

    # with a second dive held out, the free runs of the heave models run (and the marker goes)
    Path("params.yaml").write_text(yaml.safe_dump({**PARAMS, "features": {"test_trials": ["hold02"]}}))
    assert main([*args, "more/hold02"]) == 0
    assert not (root / "data/simulation" / SKIPPED).exists()
    runs = json.loads((root / "data/simulation/metrics.json").read_text())["hold02"]["free_run"]
    # seed 0 on seed 1: R² 0.9994 (ls and krr), MAE 4.9 mm/s
    assert {r["model"]: r["status"] for r in runs} == {"ls": "ok", "krr": "ok"}
    assert all(r["metrics"]["w"]["r2"] > 0.99 for r in runs)
    text = _text(root / "reports/report.html")
    assert "free runs were skipped" not in text and "Free runs on hold02" in text
