"""The CLI contract (issue 16, item 3): every documented exit code, usage errors before any stage runs, a config
mistake that stops every log, quiet SIGPIPE and Ctrl-C, quarantine entries that accumulate, `-q` as one line."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

import stages.ingest as ingest_stage
from pipeline import cli, layout
from pipeline.cli import common as cli_common
from pipeline.cli import run as cli_run
from pipeline.config import Params
from stages import common
from tests.cli.helpers import COUPLED_YAML, FakeDag, make_run_dir
from tests.io.test_ingest_stage import CSV_STREAMS, make_vehicle, write_csv_trial

REPO = Path(__file__).resolve().parents[2]


def _base(root: Path) -> list[str]:
    return ["--root", str(root), "--vehicle", str(root / "vehicle.yaml")]


# -- 2: usage errors, before any stage runs --------------------------------------------------------------------
def test_missing_log_path_is_a_usage_error_before_any_stage(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    missing = tmp_path / "nowhere.mcap"
    for command in ("run", "ingest"):
        assert cli.main([command, *_base(root), str(missing)]) == cli_common.EXIT_USAGE
        err = capsys.readouterr().err
        assert "usage error" in err and str(missing) in err
    assert cli.main(["inspect", str(missing)]) == cli_common.EXIT_USAGE
    assert cli.main(["init", str(missing), "-o", str(tmp_path / "v.yaml")]) == cli_common.EXIT_USAGE
    assert "not found" in capsys.readouterr().err
    assert dag.calls == []


def test_nothing_to_process_is_a_usage_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path, trials=())
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_USAGE
    assert "nothing to process: no log given and none under" in capsys.readouterr().err
    assert cli.main(["sync", *_base(root)]) == cli_common.EXIT_USAGE  # no ingested trial
    assert "nothing to process" in capsys.readouterr().err
    root2 = make_run_dir(tmp_path / "b")
    assert cli.main(["run", *_base(root2), "-q", "--to", "ingest"]) == cli_common.EXIT_OK
    assert cli.main(["sync", *_base(root2), "--trial", "trial09"]) == cli_common.EXIT_USAGE
    assert "available: ['trial01', 'trial02']" in capsys.readouterr().err
    assert dag.calls == [("ingest", None)]


def test_a_run_to_simulate_without_test_trials_is_refused_before_any_stage(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The simulate stage rolls the models out on an unseen trial: with no ``features.test_trials`` it failed with
    exit 3 after ingest .. decoupled had run (minutes); the run now stops at once, naming the params file, the key
    and the trials it could name. A run that stops before simulate goes on."""
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    params = root / "params.yaml"
    params.write_text(COUPLED_YAML + "features:\n  tuning_fraction: 0.2\n")
    assert cli.main(["run", *_base(root), "--params", str(params), "-q"]) == cli_common.EXIT_USAGE
    err = capsys.readouterr().err
    assert str(params) in err and "features.test_trials" in err and "['trial01', 'trial02']" in err
    assert dag.calls == []
    assert cli.main(["run", *_base(root), "--params", str(params), "-q", "--to", "decoupled"]) == cli_common.EXIT_OK
    assert [stage for stage, _ in dag.calls][-1] == "decoupled"


@pytest.mark.parametrize(("key", "value", "named"), [
    ("inputs", "[u_mps, v_mps, r_radps, rot13]", "['rot13']"),
    ("outputs", "[udot_mps2, auto]", "['auto']"),
    ("inputs", "[u_mps, v_mps, r_radps, T_th1_N, split]", "['split']"),  # in the store, but not a number
])
def test_coupled_columns_the_store_will_not_have_are_refused_before_any_stage(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], key: str, value: str,
        named: str) -> None:
    """``coupled.inputs`` / ``outputs`` naming a column the feature store will not have: the tune stage refused it
    with exit 3 after ingest .. features; the run now stops before its first stage, naming the params file, the key
    and the store's columns (known from the vehicle config). A run that stops before tune goes on."""
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    params = root / "params.yaml"
    coupled = {"models": "[rbf_svr]", "inputs": "[u_mps, v_mps, r_radps, T_th1_N]", key: value}  # outputs: SVRs only
    params.write_text("coupled:\n" + "".join(f"  {k}: {v}\n" for k, v in coupled.items())
                      + "features:\n  test_trials: [trial02]\n")
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_USAGE
    err = capsys.readouterr().err
    assert f"{params}: field 'coupled.{key}'" in err and named in err and "'T_th1_N'" in err and "'n1_rpm'" in err
    assert dag.calls == [] and not (root / layout.SIGNALS).exists()
    assert cli.main(["run", *_base(root), "-q", "--to", "features"]) == cli_common.EXIT_OK  # no tune: no check
    assert cli.main(["run", *_base(root), "-q", "--from", "train"]) == cli_common.EXIT_USAGE


def test_retrain_without_inbox_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["retrain", "--root", str(tmp_path), "--inbox", str(tmp_path / "inbox")]) == cli_common.EXIT_USAGE
    assert "inbox" in capsys.readouterr().err


# -- 2: a config mistake that stops every log ----------------------------------------------------------------
def _csv_root(tmp_path: Path, trials: tuple[str, ...] = ("trial01", "trial02")) -> Path:
    root = tmp_path / "run"
    for t in trials:
        write_csv_trial(root / layout.RAW / t)
    (root / "vehicle.yaml").write_text("stand-in: the test loads the config itself\n")
    return root


def _use_vehicle(monkeypatch: pytest.MonkeyPatch, streams: dict[str, Any]) -> None:
    monkeypatch.setenv("AUVID_JOBS", "1")
    # a run that reaches simulate needs an unseen trial, and one that reaches tune inputs its store has
    params = Params(features={"test_trials": ["trial02"]}, coupled={"inputs": ["u_mps", "v_mps", "r_radps", "T_t1_N"]})
    monkeypatch.setattr(cli_run, "_load", lambda args, stages: (make_vehicle(streams), params))


def test_misspelt_field_in_every_log_is_a_config_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    root = _csv_root(tmp_path)
    bad = json.loads(json.dumps(CSV_STREAMS))
    bad["fog"]["signals"]["n1_rpm"]["field"] = "n_1"  # misspelt column
    _use_vehicle(monkeypatch, bad)
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "config error" in err and "'n_1'" in err and "every log (2)" in err
    assert not (root / layout.SIGNALS / "quarantine.json").exists()  # not one quarantine entry per log
    assert not (root / layout.SYNCED).exists()  # and sync did not run


def test_one_bad_log_among_good_ones_is_quarantined(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str],
                                                    caplog: pytest.LogCaptureFixture) -> None:
    root = _csv_root(tmp_path)
    (root / layout.RAW / "trial03").mkdir()
    (root / layout.RAW / "trial03" / "fog.csv").write_text("t,rate\n1,2\n")  # the log lacks n1, not the config
    _use_vehicle(monkeypatch, CSV_STREAMS)
    assert cli.main(["ingest", *_base(root)]) == cli_common.EXIT_QUARANTINED
    captured = capsys.readouterr()
    assert captured.err.count("no column 'n1'") == 1  # the reason once (not also as a log warning)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING and "no column" in r.getMessage()]
    assert "ingest: 1 quarantined (trial03)" in captured.out


# -- 1: quarantine entries accumulate per log ---------------------------------------------------------------
def test_quarantine_entries_accumulate_per_log(tmp_path: Path) -> None:
    root = _csv_root(tmp_path)
    raw = root / layout.RAW
    for name in ("bad_a", "bad_b"):
        (raw / name).mkdir()
        (raw / name / "fog.csv").write_text("t,rate\n1,2\n")
    vehicle, params = make_vehicle(CSV_STREAMS), Params()
    qfile = root / layout.SIGNALS / "quarantine.json"

    def listed() -> list[str]:
        return [e["trial"] for e in json.loads(qfile.read_text())["quarantined"]]

    ingest_stage.run(root, vehicle, params, logs=[raw / "trial01", raw / "bad_a"])
    ingest_stage.run(root, vehicle, params, logs=[raw / "trial02", raw / "bad_b"])
    assert listed() == ["bad_a", "bad_b"]  # the first call's bad log is still there
    assert json.loads(qfile.read_text())["trials_written"] == ["trial01", "trial02"]
    write_csv_trial(raw / "bad_a")  # fixed, ingested again: its entry goes
    ingest_stage.run(root, vehicle, params, logs=[raw / "bad_a"])
    assert listed() == ["bad_b"]
    assert json.loads(qfile.read_text())["trials_written"] == ["bad_a", "trial01", "trial02"]


# -- -q: one line per run; salvaged logs are named --------------------------------------------------------------
def test_quiet_prints_one_summary_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    FakeDag(quarantine={"trial02"}).install(monkeypatch)
    root = make_run_dir(tmp_path)
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_QUARANTINED
    captured = capsys.readouterr()
    lines = (captured.out + captured.err).splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("auvid run: done with quarantined inputs") and "10 stage(s)" in lines[0]
    # without -q: per-stage lines, then the summary
    assert cli.main(["run", *_base(root)]) == cli_common.EXIT_QUARANTINED
    assert len(capsys.readouterr().out.splitlines()) == 2 * len(common.STAGE_ORDER) + 1


def test_salvaged_log_is_named_in_the_summary(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)
    real = dag.modules["ingest"].run

    def salvaging(root: Path, vehicle: Any, params: Any, logs: Any = None, progress: Any = None) -> common.StageResult:
        result = real(root, vehicle, params, logs=logs, progress=progress)
        result.summary["salvaged"] = ["trial02"]
        return result

    dag.modules["ingest"].run = salvaging
    root = make_run_dir(tmp_path)
    assert cli.main(["run", *_base(root), "-q", "--to", "ingest"]) == cli_common.EXIT_OK
    assert "ingest: 1 salvaged (trial02)" in capsys.readouterr().out


def test_run_stops_after_ingest_when_every_log_is_quarantined(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag(quarantine={"trial01", "trial02"}).install(monkeypatch)
    root = make_run_dir(tmp_path)
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_QUARANTINED
    assert [n for n, _ in dag.calls] == ["ingest"]
    assert "stopped after ingest: no trial left to process" in capsys.readouterr().out


# -- 130 and 141: Ctrl-C and a closed pipe end quietly -----------------------------------------------------------
def test_ctrl_c_exits_130_without_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    dag = FakeDag().install(monkeypatch)

    def interrupted(*args: Any, **kwargs: Any) -> common.StageResult:
        raise KeyboardInterrupt

    dag.modules["sync"].run = interrupted
    root = make_run_dir(tmp_path)
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_INTERRUPTED == 130
    err = capsys.readouterr().err
    assert err == "auvid: interrupted\n"


def test_a_full_disk_exits_3_naming_the_file_without_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """ENOSPC (or any OSError a stage does not turn into a PipelineError) is a failed stage: exit 3, one line."""
    import errno

    dag = FakeDag().install(monkeypatch)
    target = tmp_path / "data/synced/trial01.parquet"

    def disk_full(*args: Any, **kwargs: Any) -> common.StageResult:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    dag.modules["sync"].run = disk_full
    root = make_run_dir(tmp_path)
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_FAILED == 3
    err = capsys.readouterr().err
    assert err == f"auvid: run failed: No space left on device ({target})\n"


_BIG_INSPECT = textwrap.dedent("""\
    import sys, types
    fake = types.ModuleType("pipeline.io.inspect")
    fake.inspect_log = lambda path, **kw: {"topics": [{"topic": f"/t{i}", "count": i} for i in range(20000)]}
    fake.format_inspect = lambda info: "\\n".join(t["topic"] for t in info["topics"])
    fake.topic_fields = fake.format_fields = None
    sys.modules["pipeline.io.inspect"] = fake
    from pipeline import cli
    sys.exit(cli.main(sys.argv[1:]))
""")


@pytest.mark.parametrize("as_json", [True, False], ids=["json", "text"])
def test_closed_pipe_exits_quietly(tmp_path: Path, as_json: bool) -> None:
    """`auvid inspect LOG --json | head -1`: ~1 MB of output into a pipe whose reader has gone."""
    log = tmp_path / "x.mcap"
    log.write_bytes(b"")
    args = [sys.executable, "-c", _BIG_INSPECT, "inspect", str(log)] + (["--json"] if as_json else [])
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO, env=env)
    assert proc.stdout is not None and proc.stderr is not None
    assert proc.stdout.readline()  # `head -1`: one line, then the reader closes the pipe
    proc.stdout.close()
    err = proc.stderr.read().decode()
    code = proc.wait(timeout=60)
    assert code in (0, cli_common.EXIT_PIPE), err
    assert "Traceback" not in err and "BrokenPipeError" not in err and "Exception ignored" not in err, err


def test_closed_pipe_through_a_shell_pipeline(tmp_path: Path) -> None:
    log = tmp_path / "x.mcap"
    log.write_bytes(b"")
    script = tmp_path / "auvid_big.py"
    script.write_text(_BIG_INSPECT)
    cmd = f'"{sys.executable}" "{script}" inspect "{log}" --json | head -1; echo "status=${{PIPESTATUS[0]}}" >&2'
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, cwd=REPO, env=env, timeout=60)
    assert done.stdout == "{\n"
    status = int(done.stderr.rsplit("status=", 1)[1])
    assert status in (0, 141), done.stderr
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr


# -- the exit codes are the same everywhere they are written ---------------------------------------------------
def test_documented_exit_codes_agree() -> None:
    assert (cli_common.EXIT_OK, cli_common.EXIT_QUARANTINED, cli_common.EXIT_USAGE,
            cli_common.EXIT_FAILED) == (0, 1, 2, 3)
    assert (common.EXIT_INTERRUPTED, common.EXIT_PIPE) == (cli_common.EXIT_INTERRUPTED,
                                                           cli_common.EXIT_PIPE) == (130, 141)
    phrases = ["0 done", "1 done", "2 usage or config error", "3 a stage failed", "130 interrupted",
               "141 output pipe closed"]
    texts = {"help": cli.EPILOG, "module": cli.__doc__ or "", "stages.common": common.__doc__ or "",
             "README.md": (REPO / "README.md").read_text(),
             "docs/user-guide.md": (REPO / "docs/user-guide.md").read_text()}
    for where, text in texts.items():
        flat = " ".join(text.replace("(", " ").split()).replace("; ", ", ")
        missing = [p for p in phrases if p not in flat]
        assert not missing, (where, missing)


# -- 2: usage mistakes of `auvid inspect`; a config mistake found before any stage ------------------------------
def test_inspect_usage_mistakes_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An empty directory and a mistyped --fields topic are usage mistakes (2), listing what there is; a damaged
    log is no usage mistake (salvaged: 0, or failed: 3)."""
    from pipeline.sim import generate_trial, load_example_vehicle, write_trial

    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.main(["inspect", str(empty)]) == cli_common.EXIT_USAGE
    assert "nothing to inspect" in capsys.readouterr().err
    other = tmp_path / "notes"  # a directory of no log
    other.mkdir()
    (other / "notes.pdf").write_bytes(b"%PDF-1.7")
    assert cli.main(["inspect", str(other)]) == cli_common.EXIT_USAGE
    assert "give one log" in capsys.readouterr().err
    log = write_trial(generate_trial(load_example_vehicle(), 3.0, seed=1), "mcap", tmp_path / "run01.mcap")
    assert cli.main(["inspect", str(log), "--fields", "/fog/rat"]) == cli_common.EXIT_USAGE
    err = capsys.readouterr().err
    assert "usage error" in err and "'/fog/rat'" in err and "'/fog/rate'" in err  # the topics there are
    assert cli.main(["inspect", str(log), "--fields", "/fog/rate"]) == cli_common.EXIT_OK
    assert "header.stamp.sec" in capsys.readouterr().out
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\nnot a record" * 3)
    assert cli.main(["inspect", str(bad)]) != cli_common.EXIT_USAGE  # salvaged or failed: not the user's mistake


def test_unknown_test_trial_is_a_config_error_before_any_stage(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """features.test_trials naming no trial: exit 2 before ingest runs (not after ingest..derive), naming the key,
    the params file and the trials there are (raw logs, logs given, trials ingested before)."""
    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    params = root / "params.yaml"
    params.write_text(COUPLED_YAML + "features:\n  test_trials: [trial2]\n")
    assert cli.main(["run", *_base(root), "-q"]) == cli_common.EXIT_USAGE
    err = capsys.readouterr().err
    assert "config error" in err and "features.test_trials" in err and str(params) in err
    assert "['trial2']" in err and "its trials: ['trial01', 'trial02']" in err
    assert dag.calls == []
    assert cli.main(["run", *_base(root), "-q", "--to", "derive"]) == cli_common.EXIT_OK  # no features: no check
    elsewhere = tmp_path / "sea" / "trial2.mcap"  # a log given on the command line is a trial of the run
    elsewhere.parent.mkdir()
    elsewhere.write_text("log trial2")
    assert cli.main(["run", *_base(root), "-q", str(elsewhere)]) == cli_common.EXIT_OK
    assert ("features", None) in dag.calls
