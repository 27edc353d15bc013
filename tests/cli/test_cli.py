"""The `auvid` command: parsing, help, DAG order, exit codes, missing stages (fake stages, real runner)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline import cli
from pipeline.cli import common as cli_common
from stages import common
from tests.cli.helpers import FakeDag, make_run_dir


def test_help_teaches_with_examples(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out and "auvid demo" in out and "exit codes" in out
    for name in (*common.STAGE_ORDER, "run", "inspect", "demo", "retrain"):
        assert name in out


def test_help_texts_name_the_params_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    """A stage's help that names a setting gives its default as the params model has it, and the other values:
    `auvid differentiate --help` says the Kalman/RTS smoother, `auvid tune --help` nested tuning."""
    import re
    import typing

    from pipeline.config import Params

    defaults = Params()
    named = {}
    for stage, text in cli.STAGE_HELP.items():
        for section, key, value in re.findall(r"\(default, (\w+)\.(\w+): (\w+)[;)]", text):
            named[f"{section}.{key}"] = stage
            assert str(getattr(getattr(defaults, section), key)) == value, f"{stage} --help: {section}.{key}"
            field = type(getattr(defaults, section)).model_fields[key]
            for other in typing.get_args(field.annotation):
                assert other in text, f"{stage} --help does not name {section}.{key}: {other}"
    assert named == {"differentiate.method": "differentiate", "coupled.tuning": "tune"}
    assert "Kalman/RTS" in cli.STAGE_HELP["differentiate"]
    with pytest.raises(SystemExit):
        cli.main(["tune", "--help"])
    assert "coupled.tuning: nested" in " ".join(capsys.readouterr().out.split())


def test_every_stage_has_a_subcommand() -> None:
    parser = cli.build_parser()
    for name in common.STAGE_ORDER:
        args = parser.parse_args([name, "--root", "x"])
        assert args.command == name


def test_usage_error_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "--from", "nonsense"])
    assert exc.value.code == 2


def test_run_executes_the_dag_in_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml")])
    assert code == 0
    stages = [name for name, _ in dag.calls]
    assert stages == ["ingest", "sync", "sync", "differentiate", "differentiate", "derive", "derive",
                      "features", "tune", "train", "decoupled", "simulate", "report"]
    assert ("sync", "trial02") in dag.calls and ("derive", "trial01") in dag.calls
    out = capsys.readouterr().out
    assert "[train]" in out and "[report]" in out


def test_from_to_runs_a_slice(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    base = ["--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"]
    assert cli.main(["run", *base, "--to", "sync"]) == 0
    assert cli.main(["run", *base, "--from", "features", "--to", "train"]) == 0
    assert [n for n, _ in dag.calls] == ["ingest", "sync", "sync", "features", "tune", "train"]
    assert cli.main(["run", *base, "--from", "train", "--to", "sync"]) == 2


def test_single_stage_and_one_trial(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    base = ["--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"]
    assert cli.main(["ingest", *base]) == 0
    assert cli.main(["sync", *base, "--trial", "trial02"]) == 0
    assert dag.calls == [("ingest", None), ("sync", "trial02")]


def test_quarantine_exits_1(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                            capsys: pytest.CaptureFixture[str]) -> None:
    FakeDag(quarantine={"trial02"}).install(monkeypatch)
    root = make_run_dir(tmp_path)
    code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"])
    assert code == 1
    out = capsys.readouterr().out
    assert "ingest: 1 quarantined (trial02)" in out and "(exit 1)" in out


def test_missing_stage_fails_clearly_before_running_anything(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch, missing={"simulate"})
    root = make_run_dir(tmp_path)
    code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"])
    assert code == 3
    err = capsys.readouterr().err
    assert "simulate" in err and "missing stage" in err
    assert dag.calls == []


def test_config_error_exits_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                              capsys: pytest.CaptureFixture[str]) -> None:
    FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    (root / "params.yaml").write_text("sync: {rate_hz: -1}\n")
    code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"])
    assert code == 2
    assert "sync.rate_hz" in capsys.readouterr().err


def test_stage_failure_exits_3(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                               capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)

    def boom(root: Path, vehicle: object, params: object) -> common.StageResult:
        raise common.PipelineError("fake: not enough data", file="data/features")

    dag.modules["tune"].run = boom
    root = make_run_dir(tmp_path)
    code = cli.main(["run", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"])
    assert code == 3
    assert "not enough data" in capsys.readouterr().err


def test_progress_is_quiet_off_a_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    bar = cli_common.Progress("ingest")  # pytest's stdout is not a TTY
    bar("trial01")
    bar(3, 10, "fold 3")
    bar.update(2)
    bar.close()
    assert bar.done == 5 and bar.total == 10
    assert capsys.readouterr().out == ""


def test_progress_draws_when_enabled(capsys: pytest.CaptureFixture[str]) -> None:
    bar = cli_common.Progress("search", enabled=True)
    bar(1, 4, "fold 1")
    bar(4, 4)
    bar.close()
    assert "search" in capsys.readouterr().out


def test_inspect_json(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import json
    import sys
    import types

    fake = types.ModuleType("pipeline.io.inspect")
    fake.inspect_log = lambda path, **kw: {"file": str(path), "topics": [{"topic": "/dvl", "count": 3}]}
    fake.format_inspect = lambda info: f"{info['file']}: {len(info['topics'])} topic(s)"
    fake.topic_fields = lambda path, topic, **kw: {"topic": topic, "msgtype": "x/msg/Y", "fields": ["a.b"]}
    fake.format_fields = lambda fields: f"{fields['topic']}: {fields['fields']}"
    monkeypatch.setitem(sys.modules, "pipeline.io.inspect", fake)
    (tmp_path / "x.mcap").write_bytes(b"")
    assert cli.main(["inspect", str(tmp_path / "x.mcap"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["topics"][0]["topic"] == "/dvl"
    assert cli.main(["inspect", str(tmp_path / "x.mcap")]) == 0
    assert "1 topic(s)" in capsys.readouterr().out
    assert cli.main(["inspect", str(tmp_path / "x.mcap"), "--fields", "/dvl"]) == 0
    assert "/dvl: ['a.b']" in capsys.readouterr().out


def test_demo_lays_out_a_run_and_prints_the_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    import types

    from pipeline import demo
    from tests.cli.helpers import VEHICLE_YAML

    def fake_example(target: Path, duration_s: float, seed: int) -> types.SimpleNamespace:
        target.mkdir(parents=True)
        (target / "vehicle.yaml").write_text(VEHICLE_YAML)
        logs = []
        for name in ("trial01", "trial02", "trial03"):
            (target / f"{name}.mcap").write_text(f"log {name}")
            logs.append(target / f"{name}.mcap")
        return types.SimpleNamespace(vehicle=target / "vehicle.yaml", trials=logs)

    dag = FakeDag().install(monkeypatch)
    monkeypatch.setattr(demo, "_generate_logs", fake_example)

    def report(root: Path, vehicle: object, params: object) -> common.StageResult:
        out = Path(root) / "reports/report.html"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text("<html></html>")
        return common.StageResult("report", outputs=[out])

    dag.modules["report"].run = report
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out), "-q"]) == 0
    assert sorted(p.name for p in (out / "data/raw").iterdir()) == ["trial01.mcap", "trial02.mcap", "trial03.mcap"]
    assert (out / "vehicle.yaml").exists() and not (out / ".example").exists()
    params = (out / "params.yaml").read_text()
    assert "trial03" in params  # the last trial is held out as the unseen test trial
    assert f"report: {out / 'reports/report.html'}" in capsys.readouterr().out
    assert [n for n, _ in dag.calls][:2] == ["ingest", "sync"]


def test_vehicle_defaults_to_the_run_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["ingest", "--root", str(root), "-q"]) == 0
    assert dag.calls == [("ingest", None)]
    monkeypatch.chdir(root.parent.parent)
    assert cli.main(["ingest", "--root", str(tmp_path / "nowhere"), "-q"]) == 2  # no vehicle config anywhere
