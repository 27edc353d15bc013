"""`auvid models list|show|promote|rollback` on a registry built by real retrain runs over fake stages."""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline import cli, registry
from pipeline.cli import common as cli_common
from pipeline.retrain import RetrainOptions, retrain
from tests.cli.helpers import VEHICLE_YAML, FakeDag

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """v0001 promoted (first), v0002 rejected (0.4 < 0.5), v0003 promoted (0.9), v0004 rejected (0.8)."""
    root, inbox = tmp_path / "home", tmp_path / "inbox"
    root.mkdir()
    inbox.mkdir()
    (root / "vehicle.yaml").write_text(VEHICLE_YAML)
    for k, score in enumerate((0.5, 0.4, 0.9, 0.8), start=1):
        FakeDag(score=score).install(monkeypatch)
        names = ("trial01", "trial02") if k == 1 else (f"trial0{k + 1}",)
        for name in names:
            (inbox / f"{name}.mcap").write_text(f"log {name}")
        retrain(RetrainOptions(root=root, inbox=inbox, vehicle_path=root / "vehicle.yaml"))
    data = registry.load(root)
    assert [(v["version"], v["status"]) for v in data["versions"]] == [
        ("v0001", "promoted"), ("v0002", "rejected"), ("v0003", "promoted"), ("v0004", "rejected")]
    return root


def _models(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = cli.main(["models", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_list_is_a_table_with_the_current_version_marked(home: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _models(capsys, "list", "--root", str(home))
    assert code == cli_common.EXIT_OK
    lines = out.splitlines()
    assert lines[0].split() == ["version", "status", "created_at", "holdout_r2", "parent", "reason"]
    assert len(lines) == 5
    current = [line for line in lines if line.startswith("*")]
    assert len(current) == 1 and current[0].split()[1:6] == ["v0003", "promoted", current[0].split()[3], "0.9",
                                                            "v0001"]
    v2 = next(line for line in lines if "v0002" in line.split()[:2])
    assert "rejected" in v2 and "0.4" in v2 and "does not beat current v0001" in v2


def test_list_json_for_machines(home: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _models(capsys, "list", "--root", str(home), "--json", "-q")
    rows = json.loads(out)
    assert code == 0 and [r["version"] for r in rows] == ["v0001", "v0002", "v0003", "v0004"]
    assert [r["current"] for r in rows] == [False, False, True, False]
    assert rows[1] == {**rows[1], "status": "rejected", "holdout_score": 0.4, "parent": "v0001"}
    assert set(rows[0]) == {"version", "current", "status", "created_at", "holdout_score", "parent", "reason"}


def test_show_gives_lineage_metrics_and_reason(home: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _models(capsys, "show", "v0004", "--root", str(home))
    assert code == 0
    assert out.startswith("v0004: rejected\n")
    assert "holdout_r2 0.8 does not beat current v0003 (0.9) on the holdout" in out
    assert "lineage           v0004 <- v0003 <- v0001" in out
    assert "holdout_r2 0.8" in out and "trial05.mcap" in out and "on trial02" in out
    code, out, _ = _models(capsys, "show", "v0001", "--root", str(home), "--json")
    info = json.loads(out)
    assert info["chain"] == ["v0001"] and info["reason"] == "first model" and info["current"] is False
    assert info["lineage"]["holdout"] == ["trial02"]


@pytest.mark.parametrize("args", [["show", "v0009"], ["promote", "v0009"], ["promote", "../etc"]])
def test_unknown_version_is_a_usage_error(home: Path, capsys: pytest.CaptureFixture[str], args: list[str]) -> None:
    before = registry.registry_path(home).read_bytes()
    code, out, err = _models(capsys, *args, "--root", str(home))
    assert code == cli_common.EXIT_USAGE and out == ""
    assert f"unknown model version {args[1]!r}; registered: ['v0001', 'v0002', 'v0003', 'v0004']" in err
    assert registry.registry_path(home).read_bytes() == before


def test_no_registry_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for args in (["list"], ["show", "v0001"], ["promote", "v0001"], ["rollback"]):
        code, _, err = _models(capsys, *args, "--root", str(tmp_path))
        assert code == cli_common.EXIT_USAGE and "no model registry at" in err
    assert not (tmp_path / "registry.json").exists()


def test_promote_then_rollback(home: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _models(capsys, "promote", "v0004", "--root", str(home))
    assert code == 0 and out == "models promote: v0004 is current (was v0003)\n"
    data = registry.load(home)
    v4 = registry.version(data, "v0004")
    assert data["current"] == "v0004" and v4["status"] == "promoted"
    assert "does not beat" in v4["reason"]  # retraining's verdict is kept; the manual act is an event
    assert v4["events"][0] | {"at": None} == {"at": None, "action": "promote", "from": "v0003", "to": "v0004",
                                              "note": "promoted by hand"}
    assert (home / "current").resolve() == (home / "models/v0004").resolve()
    assert sorted(p.name for p in home.iterdir() if p.name.startswith(".")) == [".retrain.lock"]  # no temp file

    code, out, _ = _models(capsys, "promote", "v0004", "--root", str(home), "-q")
    assert code == 0 and "nothing changed" in out

    code, out, _ = _models(capsys, "rollback", "--root", str(home))
    assert code == 0 and out == "models rollback: v0003 is current (was v0004)\n"  # v0004's parent
    data = registry.load(home)
    assert data["current"] == "v0003" and registry.version(data, "v0004")["status"] == "rolled_back"
    assert (home / "current").resolve() == (home / "models/v0003").resolve()
    code, out, _ = _models(capsys, "show", "v0004", "--root", str(home))
    assert "rollback" in out and "v0004 -> v0003" in out

    assert _models(capsys, "rollback", "--root", str(home))[0] == 0  # v0003 -> v0001
    code, _, err = _models(capsys, "rollback", "--root", str(home))
    assert code == cli_common.EXIT_USAGE and "v0001 has no parent" in err
    assert registry.load(home)["current"] == "v0001"


def test_a_retrain_after_rollback_competes_with_the_restored_model(home: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    registry.rollback(home)  # v0003 -> v0001 (0.5)
    FakeDag(score=0.6).install(monkeypatch)
    inbox = home.parent / "inbox"
    (inbox / "trial07.mcap").write_text("log trial07")
    outcome = retrain(RetrainOptions(root=home, inbox=inbox, vehicle_path=home / "vehicle.yaml"))
    assert outcome.status == "promoted" and "beats current v0001" in outcome.message
    assert registry.version(registry.load(home), "v0005")["parent"] == "v0001"


def test_promote_waits_for_no_one_while_a_retrain_holds_the_lock(home: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    before = registry.registry_path(home).read_bytes()
    with open(home / registry.LOCK_FILE, "a+") as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        for args in (["promote", "v0002"], ["rollback"]):
            code, out, err = _models(capsys, *args, "--root", str(home))
            assert code == cli_common.EXIT_FAILED and out == ""
            assert "holds" in err and "nothing changed" in err
    assert registry.registry_path(home).read_bytes() == before
    assert (home / "current").resolve() == (home / "models/v0003").resolve()


def test_promote_refuses_a_version_without_its_model_directory(home: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    (home / "models/v0002").rename(home / "v0002.moved")
    code, _, err = _models(capsys, "promote", "v0002", "--root", str(home))
    assert code == cli_common.EXIT_USAGE and "has no model directory" in err
    assert registry.load(home)["current"] == "v0003"


def test_list_into_a_closed_pipe_is_quiet(tmp_path: Path) -> None:
    data = registry.empty()
    data["versions"] = [{"version": f"v{k:04d}", "status": "rejected", "created_at": "2026-01-01T00:00:00Z",
                         "holdout_score": 0.1, "parent": None, "reason": "x" * 60} for k in range(1, 3001)]
    registry.save(tmp_path, data)
    cmd = (f'"{sys.executable}" -m pipeline.cli models list --root "{tmp_path}" | head -1; '
           'echo "status=${PIPESTATUS[0]}" >&2')
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, cwd=REPO, env=env, timeout=60)
    assert done.stdout.split() == ["version", "status", "created_at", "holdout", "score", "parent", "reason"]
    assert int(done.stderr.rsplit("status=", 1)[1]) in (0, 141)
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr
