"""Fake stages with the real stage contract, for testing the CLI, the DAG runner and retraining."""

from __future__ import annotations

import json
import types
from pathlib import Path
from typing import Any

import pytest

from pipeline.ingest import trial_id
from stages import common
from stages.common import StageResult

VEHICLE_YAML = """\
name: fakebot
rigid_body: {mass_kg: 10.0, inertia_kgm2: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
added_mass: [[1,0,0,0,0,0],[0,1,0,0,0,0],[0,0,1,0,0,0],[0,0,0,1,0,0],[0,0,0,0,1,0],[0,0,0,0,0,1]]
thrusters:
  - {name: th1, speed_signal: n1_rpm, position_m: [0, 0, 0], direction: [1, 0, 0], thrust: {k_fwd_N_per_rpm2: 1.0e-6}}
sensors:
  dvl: {velocity: [dvl_x_mps, dvl_y_mps, dvl_z_mps]}
  attitude: {yaw: yaw_rad}
streams:
  nav:
    topic: /nav
    clock: log
    signals:
      dvl_x_mps: {field: vx}
      dvl_y_mps: {field: vy}
      dvl_z_mps: {field: vz}
      yaw_rad: {field: yaw}
      n1_rpm: {field: n1}
"""

#: params naming the SVR inputs fakebot's feature store has (one thruster: the default names th1 .. th3)
COUPLED_YAML = "coupled:\n  inputs: [u_mps, v_mps, r_radps, T_th1_N]\n"


class FakeDag:
    """Fake stage modules writing tiny JSON files where the real ones write Parquet; records the calls."""

    def __init__(self, fail_at: str | None = None, quarantine: set[str] | None = None,
                 score: float = 0.5) -> None:
        self.calls: list[tuple[str, str | None]] = []
        self.fail_at = fail_at
        self.quarantine = quarantine or set()
        self.score = score
        self.modules = {name: self._module(name) for name in common.STAGE_ORDER}

    def _module(self, name: str) -> types.ModuleType:
        module = types.ModuleType(f"stages.{name}")
        dag = self

        if name == "ingest":
            def run(root: Path, vehicle: Any, params: Any, logs: list[Path] | None = None,
                    progress: Any = None) -> StageResult:
                dag.calls.append((name, None))
                result = StageResult(stage=name)
                logs = list(logs) if logs else sorted((Path(root) / "data/raw").iterdir())
                for log in logs:
                    trial = trial_id(log)
                    if trial in dag.quarantine:
                        result.quarantined.append({"file": str(log), "reason": "fake: unreadable", "trial": trial})
                        continue
                    out = Path(root) / "data/signals" / trial / "ingest_report.json"
                    out.parent.mkdir(parents=True, exist_ok=True)
                    out.write_text(json.dumps({"trial": trial, "bytes": Path(log).read_text()}))
                    result.outputs.append(out)
                    if progress is not None:
                        progress(trial)
                dag._maybe_fail(name)
                return result
        elif name in common.PER_TRIAL:
            def run(root: Path, vehicle: Any, params: Any, trial: str | None = None) -> StageResult:
                dag.calls.append((name, trial))
                dag._maybe_fail(name)
                sub = {"sync": "data/synced", "differentiate": "data/kinematics", "derive": "data/derived"}[name]
                out = Path(root) / sub / f"{trial}.parquet"
                out.parent.mkdir(parents=True, exist_ok=True)
                out.write_text(name)
                return StageResult(stage=name, outputs=[out])
        else:
            def run(root: Path, vehicle: Any, params: Any) -> StageResult:
                dag.calls.append((name, None))
                dag._maybe_fail(name)
                root = Path(root)
                out = root / "data" / name / "done.json"
                if name == "train":
                    out = root / "data/models/coupled/model.json"
                    trials = sorted(p.stem for p in (root / "data/derived").glob("*.parquet"))
                    out.parent.mkdir(parents=True, exist_ok=True)
                    out.write_text(json.dumps({"trials": trials}))
                    ev = root / "data/evaluation/coupled/metrics.json"  # the train stage's shape
                    ev.parent.mkdir(parents=True, exist_ok=True)
                    ev.write_text(json.dumps({"fake_svr": {"udot_mps2": {"cv_test_r2": dag.score, "cv_test_r2_sd": 0.0,
                                                                         "final_r2": dag.score}}}))
                    return StageResult(stage=name, outputs=[out, ev])
                out.parent.mkdir(parents=True, exist_ok=True)
                out.write_text("{}")
                return StageResult(stage=name, outputs=[out])
        module.run = run
        module.main = lambda argv=None: 0
        return module

    def _maybe_fail(self, name: str) -> None:
        if self.fail_at == name:
            raise RuntimeError(f"injected crash in {name}")

    def install(self, monkeypatch: pytest.MonkeyPatch, missing: set[str] | None = None) -> FakeDag:
        missing = missing or set()

        def load_stage(name: str) -> types.ModuleType:
            if name in missing or name not in self.modules:
                raise common.MissingStageError(f"stage {name!r} is not available (no module stages/{name}.py)")
            return self.modules[name]

        monkeypatch.setattr(common, "load_stage", load_stage)
        monkeypatch.setenv("AUVID_JOBS", "1")  # per-trial fan-out inline: fakes are not importable in workers
        monkeypatch.delenv("AUVID_SCHEDULER", raising=False)
        return self


def make_run_dir(tmp_path: Path, trials: tuple[str, ...] = ("trial01", "trial02")) -> Path:
    root = tmp_path / "run"
    raw = root / "data/raw"
    raw.mkdir(parents=True)
    for t in trials:
        (raw / f"{t}.mcap").write_text(f"log {t}")
    (root / "vehicle.yaml").write_text(VEHICLE_YAML)
    # a run that reaches simulate needs an unseen trial, and one that reaches tune SVR inputs fakebot's store has
    (root / "params.yaml").write_text(COUPLED_YAML + (f"features:\n  test_trials: [{trials[-1]}]\n" if trials else ""))
    return root
