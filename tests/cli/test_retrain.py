"""Scheduled retraining with fake stages: idempotence, promotion rule, fixed holdout, crash safety, the lock."""

from __future__ import annotations

import fcntl
import json
from pathlib import Path

import pytest

from pipeline import cli, registry
from pipeline.retrain import LOCK_FILE, RetrainOptions, holdout_score, retrain
from tests.cli.helpers import VEHICLE_YAML, FakeDag


def _home(tmp_path: Path, logs: tuple[str, ...] = ("trial01", "trial02")) -> tuple[Path, Path]:
    root, inbox = tmp_path / "home", tmp_path / "inbox"
    root.mkdir()
    inbox.mkdir()
    (root / "vehicle.yaml").write_text(VEHICLE_YAML)
    for name in logs:
        (inbox / f"{name}.mcap").write_text(f"log {name}")
    return root, inbox


def _opts(root: Path, inbox: Path) -> RetrainOptions:
    return RetrainOptions(root=root, inbox=inbox, vehicle_path=root / "vehicle.yaml")


def _snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*"))
            if p.is_file() and not p.is_symlink() and p.name != LOCK_FILE}


def _home_with_champion(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, Path]:
    """A retraining home whose first run promoted v0001 (holdout score 0.5)."""
    FakeDag(score=0.5).install(monkeypatch)
    root, inbox = _home(tmp_path)
    retrain(_opts(root, inbox))
    return root, inbox


def test_first_run_promotes_second_does_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dag = FakeDag(score=0.5).install(monkeypatch)
    root, inbox = _home(tmp_path)
    first = retrain(_opts(root, inbox))
    assert first.status == "promoted" and first.version == "v0001"
    data = registry.load(root)
    assert data["current"] == "v0001" and data["holdout"]["trials"] == ["trial02"]
    assert len(data["seen_logs"]) == 2
    assert (root / "current").resolve() == (root / "models/v0001").resolve()
    assert (root / "models/v0001/data/models/coupled/model.json").exists()
    lineage = data["versions"][0]["lineage"]
    assert {e["name"] for e in lineage["new_logs"]} == {"trial01.mcap", "trial02.mcap"}
    assert lineage["holdout"] == ["trial02"] and lineage["vehicle_hash"]

    before, calls = _snapshot(root), len(dag.calls)
    second = retrain(_opts(root, inbox))
    assert second.status == "nothing_new"
    assert _snapshot(root) == before and len(dag.calls) == calls


def test_new_log_worse_is_rejected_better_is_promoted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    FakeDag(score=0.5).install(monkeypatch)
    root, inbox = _home(tmp_path)
    retrain(_opts(root, inbox))

    dag = FakeDag(score=0.4).install(monkeypatch)
    (inbox / "trial03.mcap").write_text("log trial03")
    worse = retrain(_opts(root, inbox))
    assert worse.status == "rejected"
    # only the new log was ingested; old trials' per-trial outputs were reused, not recomputed
    assert dag.calls[0] == ("ingest", None)
    assert [t for s, t in dag.calls if s == "sync"] == ["trial03"]
    data = registry.load(root)
    assert data["current"] == "v0001" and data["store"] == "stores/v0002"
    assert data["versions"][1]["status"] == "rejected" and "does not beat" in data["versions"][1]["reason"]
    assert data["holdout"]["trials"] == ["trial02"]  # fixed
    assert json.loads((root / "models/v0001/data/models/coupled/model.json").read_text())["trials"] == [
        "trial01", "trial02"]

    FakeDag(score=0.9).install(monkeypatch)
    (inbox / "trial04.mcap").write_text("log trial04")
    better = retrain(_opts(root, inbox))
    assert better.status == "promoted" and better.version == "v0003"
    data = registry.load(root)
    assert data["current"] == "v0003" and data["versions"][2]["parent"] == "v0001"
    model = json.loads((root / "current/data/models/coupled/model.json").read_text())
    assert model["trials"] == ["trial01", "trial02", "trial03", "trial04"]
    assert sorted(p.name for p in (root / "stores").iterdir()) == ["v0003"]


def test_a_candidate_that_only_ties_the_champion_is_rejected(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Promotion needs a strictly better holdout score: a tie keeps the current model (no churn on equal data)."""
    root, inbox = _home_with_champion(tmp_path, monkeypatch)
    FakeDag(score=0.5).install(monkeypatch)
    (inbox / "trial03.mcap").write_text("log trial03")
    tie = retrain(_opts(root, inbox))
    assert tie.status == "rejected"
    assert registry.load(root)["current"] == "v0001"


@pytest.mark.parametrize("stage", ["ingest", "derive", "train", "report"])
def test_crash_leaves_registry_and_current_model_intact(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        stage: str) -> None:
    root, inbox = _home_with_champion(tmp_path, monkeypatch)
    before = _snapshot(root)

    FakeDag(score=0.9, fail_at=stage).install(monkeypatch)
    (inbox / "trial03.mcap").write_text("log trial03")
    with pytest.raises(RuntimeError, match="injected crash"):
        retrain(_opts(root, inbox))
    after = {k: v for k, v in _snapshot(root).items() if not k.startswith("staging/")}
    assert after == before
    assert (root / "current").resolve() == (root / "models/v0001").resolve()

    FakeDag(score=0.9).install(monkeypatch)  # the next run recovers and picks the log up
    outcome = retrain(_opts(root, inbox))
    assert outcome.status == "promoted" and outcome.version == "v0002"
    assert not (root / "staging").exists()


def test_crash_at_the_commit_point(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root, inbox = _home_with_champion(tmp_path, monkeypatch)
    FakeDag(score=0.9).install(monkeypatch)
    (inbox / "trial03.mcap").write_text("log trial03")

    def power_cut(*args: object) -> None:
        raise OSError("disk went away")

    with monkeypatch.context() as m:
        m.setattr(registry, "save", power_cut)
        with pytest.raises(OSError):
            retrain(_opts(root, inbox))
    data = registry.load(root)
    assert data["current"] == "v0001" and data["store"] == "stores/v0001"
    assert (root / "stores/v0001/data/raw/trial01.mcap").exists()
    outcome = retrain(_opts(root, inbox))  # orphans from the cut are cleaned, the log is picked up again
    assert outcome.status == "promoted"
    assert sorted(p.name for p in (root / "stores").iterdir()) == [outcome.version]


def test_second_concurrent_run_exits_cleanly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)
    root, inbox = _home(tmp_path)
    with open(root / LOCK_FILE, "a+") as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert retrain(_opts(root, inbox)).status == "locked"
        code = cli.main(["retrain", "--root", str(root), "--inbox", str(inbox), "-q"])
        assert code == 0
        assert "another retrain" in capsys.readouterr().out
    assert dag.calls == [] and not (root / "registry.json").exists()
    assert cli.main(["retrain", "--root", str(root), "--inbox", str(inbox), "-q"]) == 0
    assert registry.load(root)["current"] == "v0001"


def test_quarantined_new_log_exit_1_and_not_retried(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    FakeDag(quarantine={"trial03"}).install(monkeypatch)
    root, inbox = _home(tmp_path, ("trial01", "trial02", "trial03"))
    assert cli.main(["retrain", "--root", str(root), "--inbox", str(inbox), "-q"]) == 1
    data = registry.load(root)
    assert data["versions"][0]["lineage"]["quarantined"][0]["trial"] == "trial03"
    assert retrain(_opts(root, inbox)).status == "nothing_new"


def test_holdout_score_picks_the_cv_best_coupled_model(tmp_path: Path) -> None:
    ev = tmp_path / "data/evaluation/coupled"
    ev.mkdir(parents=True)
    (ev / "metrics.json").write_text(json.dumps({
        "wdse_svr": {"udot": {"cv_test_r2": 0.9, "cv_test_r2_sd": 0.1, "final_r2": 0.7},
                     "vdot": {"cv_test_r2": 0.8, "cv_test_r2_sd": 0.1, "final_r2": 0.5}},
        "rbf_svr": {"udot": {"cv_test_r2": 0.6, "cv_test_r2_sd": 0.1, "final_r2": 0.99}}}))
    score = holdout_score(tmp_path, ["trial03"])
    assert score["model"] == "wdse_svr" and score["holdout_r2"] == pytest.approx(0.6)
    assert score["scored_on"] == "holdout"


def test_holdout_score_generic_fallback(tmp_path: Path) -> None:
    ev = tmp_path / "data/evaluation/other"
    ev.mkdir(parents=True)
    (ev / "summary.json").write_text(json.dumps({"m": {"test": {"r2": 0.8, "r2_sd": 0.1}, "train": {"r2": 1.0}},
                                                 "n": {"holdout": {"r2": 0.6}}}))
    assert holdout_score(tmp_path, [])["holdout_r2"] == pytest.approx(0.7)
    with pytest.raises(Exception, match="no holdout"):
        holdout_score(tmp_path / "nothing", [])


def test_inbox_logs_with_unsafe_names_are_refused_every_night_never_copied(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """'trial 03.mcap' and 'trial 04.mcap' (a space): exit 1 with both quarantined, naming file and rule, on every
    run; never copied into the store (where every later rebuild would meet them); the inbox files untouched."""
    FakeDag().install(monkeypatch)
    root, inbox = _home(tmp_path, ("trial01", "trial02", "trial 03", "trial 04"))
    before = {p.name: p.read_bytes() for p in inbox.iterdir()}
    for _night in range(2):
        assert cli.main(["retrain", "--root", str(root), "--inbox", str(inbox), "-q"]) == 1
    outcome = retrain(_opts(root, inbox))
    assert outcome.status == "nothing_new"
    data = registry.load(root)
    for entries in (outcome.quarantined, data["versions"][0]["lineage"]["quarantined"]):
        assert sorted(Path(e["file"]).name for e in entries) == ["trial 03.mcap", "trial 04.mcap"]
        for e in entries:
            assert repr(Path(e["file"]).stem) in e["reason"]
            assert "not a safe name" in e["reason"] and "letters, digits" in e["reason"]
    assert data["current"] == "v0001" and len(data["versions"]) == 1 and len(data["seen_logs"]) == 2
    assert sorted(p.name for p in (root / data["store"] / "data/raw").iterdir()) == ["trial01.mcap", "trial02.mcap"]
    assert {p.name: p.read_bytes() for p in inbox.iterdir()} == before
