"""A report built by ``auvid retrain`` compares the candidate with the current version, model by model."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from pipeline.report import compare
from pipeline.retrain import RetrainOptions, retrain
from tests.cli.helpers import VEHICLE_YAML, FakeDag


def _retrain(root: Path, inbox: Path, score: float, monkeypatch: pytest.MonkeyPatch,
             seen: list[Any] | None = None) -> str:
    dag = FakeDag(score=score).install(monkeypatch)
    if seen is not None:  # the report stage sees what the real one would read
        report = dag.modules["report"]
        fake = report.run

        def spy(run_root: Path, vehicle: Any, params: Any) -> Any:
            seen.append(compare.rows(json.loads((run_root / compare.BASELINE).read_text())["scores"],
                                     compare.scores(run_root), "v0001"))
            return fake(run_root, vehicle, params)

        report.run = spy
    outcome = retrain(RetrainOptions(root=root, inbox=inbox, vehicle_path=root / "vehicle.yaml"))
    return str(outcome.version)


def test_a_retrained_report_names_the_better_of_candidate_and_current_per_model(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root, inbox = tmp_path / "home", tmp_path / "inbox"
    root.mkdir()
    inbox.mkdir()
    (root / "vehicle.yaml").write_text(VEHICLE_YAML)
    for name in ("trial01", "trial02"):
        (inbox / f"{name}.mcap").write_text(f"log {name}")
    assert _retrain(root, inbox, 0.5, monkeypatch) == "v0001"
    assert not (root / "models/v0001" / compare.BASELINE).exists()  # the first version has nothing to compare
    (inbox / "trial03.mcap").write_text("log trial03")
    seen: list[Any] = []
    assert _retrain(root, inbox, 0.7, monkeypatch, seen) == "v0002"
    assert seen == [[{"output": "u̇ [m/s²]", "model": "fake_svr", "score": "R² on the holdout",
                      "current (v0001)": 0.5, "candidate": 0.7, "better": "candidate"}]]
    # the comparison stays with the candidate's files
    kept = json.loads((root / "models/v0002" / compare.BASELINE).read_text())
    assert kept["version"] == "v0001" and kept["scores"][0]["score"] == 0.5


def test_the_comparison_table_lets_a_failed_model_lose_and_lower_mae_win() -> None:
    current = [{"output": "udot_mps2", "model": "wdse_svr", "score": 0.9, "metric": "R² on the holdout",
                "higher_is_better": True, "failed": False},
               {"output": "d_v", "model": "gp", "score": 1.05, "metric": "CV test MAE", "higher_is_better": False,
                "failed": False},
               {"output": "d_v", "model": "ls", "score": 0.98, "metric": "CV test MAE", "higher_is_better": False,
                "failed": False}]
    candidate = [{**current[0], "score": 0.95, "failed": True}, {**current[1], "score": 1.00},
                 {**current[2], "score": 0.99}]
    rows = compare.rows(current, candidate, "v0003")
    assert {(r["output"], r["model"]): r["better"] for r in rows} == {
        ("u̇ [m/s²]", "WDSE-SVR"): "v0003 (candidate failed)", ("d_v", "GP"): "candidate", ("d_v", "LS"): "v0003"}


def test_the_report_shows_the_comparison_only_for_a_candidate(study_dir: Path) -> None:
    from tests.report.test_report import _build, _section, _write

    assert "Candidate against the current version" not in _build(study_dir).read_text()
    _write(study_dir / "data/evaluation/coupled/metrics.json", {"wdse_svr": {"udot_mps2": {"final_r2": 0.8}}})
    _write(study_dir / compare.BASELINE, {"version": "v0007", "scores": [
        {"output": "udot_mps2", "model": "wdse_svr", "score": 0.85, "metric": "R² on the holdout",
         "higher_is_better": True, "failed": False}]})
    summary = _section(_build(study_dir).read_text(), "summary")
    assert "Candidate against the current version" in summary and "v0007" in summary
    assert summary.split("Candidate against", 1)[1].count(">v0007</td>") == 1  # WDSE-SVR: current is better
