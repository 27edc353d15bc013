"""Config snapshots (issue 15, imports on a budget): ``auvid ingest`` reads a vehicle config and params it validated
before from a snapshot, without pydantic, and writes the same bytes as when it validated them; anything that could
make the snapshot wrong (other bytes, other code, a damaged file) validates again."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pickle
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from pydantic import BaseModel

from pipeline import layout
from pipeline.cli import main
from pipeline.config import Vehicle, config_hash, snapshot
from pipeline.errors import ConfigError
from tests.config.test_trial_overrides import with_trials
from tests.io import helpers as io
from tests.io.test_import_budget import VEHICLE as BUDGET_VEHICLE
from tests.sync.test_optional_streams import csv_trial

ROOT = Path(__file__).resolve().parents[2]
DAGON = ROOT / "pipeline" / "sim" / "dagon.yaml"
PARAMS = ROOT / "params.yaml"
#: trial02's depth file is named otherwise and its nav clock is 0.25 s late: an override for that trial only
OVERRIDES = {"trial02": {"streams": {"nav": {"offset_s": 0.25}, "depth": {"file": "pressure.csv"}}},
             "sea*": {"streams": {"depth": {"optional": True}}}}


def overridden_vehicle(path: Path) -> Path:
    doc = with_trials(OVERRIDES).model_dump(mode="json", exclude_unset=True)
    path.write_text(yaml.safe_dump({**doc, "trials": OVERRIDES}, sort_keys=False), encoding="utf-8")
    return path


def two_trials(root: Path) -> None:
    csv_trial(root / layout.RAW / "trial01", depth=True)
    (csv_trial(root / layout.RAW / "trial02", depth=True) / "depth_a.csv").rename(
        root / layout.RAW / "trial02" / "pressure.csv")


def outputs(root: Path) -> dict[str, bytes]:
    signals = root / layout.SIGNALS
    return {p.relative_to(signals).as_posix(): p.read_bytes() for p in sorted(signals.rglob("*")) if p.is_file()}


def snapshots(cache: Path) -> list[Path]:
    return sorted((cache / "configs").glob("*.json"))


def no_validation(monkeypatch: pytest.MonkeyPatch) -> None:
    """From here on a miss fails the test: what follows is answered by the snapshot."""
    def refuse(*_: Any) -> None:
        raise AssertionError("the configs were validated again: the snapshot was not used")
    monkeypatch.setattr(snapshot, "_validate", refuse)


def test_second_ingest_reads_the_snapshot_and_writes_the_same_bytes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, _config_snapshots_per_test: Path) -> None:
    root = tmp_path / "run"
    two_trials(root)
    vehicle = overridden_vehicle(tmp_path / "vehicle.yaml")
    (root / "params.yaml").write_bytes(PARAMS.read_bytes())
    command = ["ingest", "-q", "--root", str(root), "--vehicle", str(vehicle)]
    assert main(command) == 0
    validated = outputs(root)
    assert len(snapshots(_config_snapshots_per_test)) == 1
    report = json.loads(validated["trial02/ingest_report.json"])
    assert report["streams"]["nav"]["offset_s"] == 0.25  # the override reached trial02 ...
    assert json.loads(validated["trial01/ingest_report.json"])["streams"]["nav"]["offset_s"] == 0.0  # only it

    no_validation(monkeypatch)
    assert main(command) == 0
    assert outputs(root) == validated  # values, provenance (config hash, trial overrides), report: every byte
    assert main([*command, "--no-checksum"]) == 0  # the params view takes the command line's override
    assert json.loads(layout.ingest_report_path(root, "trial01").read_text())["checksum"] == "none"


def assert_same_values(view: Any, model: Any, where: str) -> None:
    """The view holds what the model holds: the same types (a tuple stays a tuple), the same dict order."""
    if isinstance(model, BaseModel):
        assert isinstance(view, snapshot.ConfigView) and view._model == type(model).__name__, where
        assert set(view._fields) == set(type(model).model_fields), where
        for name in type(model).model_fields:
            assert_same_values(getattr(view, name), getattr(model, name), f"{where}.{name}")
    elif isinstance(model, dict):
        assert type(view) is dict and list(view) == list(model), where
        for key in model:
            assert_same_values(view[key], model[key], f"{where}.{key}")
    elif isinstance(model, list | tuple):
        assert type(view) is type(model) and len(view) == len(model), where
        for i, (v, m) in enumerate(zip(view, model, strict=True)):
            assert_same_values(v, m, f"{where}.{i}")
    else:
        assert type(view) is type(model) and view == model, where


@pytest.mark.parametrize("which", ["dagon", "overrides"])
def test_views_hold_what_the_models_hold(tmp_path: Path, which: str) -> None:
    path = DAGON if which == "dagon" else overridden_vehicle(tmp_path / "vehicle.yaml")
    vehicle, params = snapshot.load_for_ingest(path, PARAMS)
    assert isinstance(vehicle, Vehicle)  # validated: nothing was there
    view, pview = snapshot.load_for_ingest(path, PARAMS)
    assert isinstance(view, snapshot.VehicleView) and isinstance(pview, snapshot.ConfigView)
    assert_same_values(view, vehicle, "vehicle")
    assert_same_values(pview, params, "params")
    assert view.model_dump(mode="json") == vehicle.model_dump(mode="json")
    assert config_hash(view) == config_hash(vehicle) and config_hash(pview) == config_hash(params)
    assert view.resolve("msgs") == vehicle.resolve("msgs") == path.resolve().parent / "msgs"
    assert view.signal_names() == vehicle.signal_names()
    for trial in ("trial01", "trial02", "sea7", "sea*"):
        assert view.trial_overrides(trial) == vehicle.trial_overrides(trial)
    assert_same_values(pickle.loads(pickle.dumps(view)), vehicle, "pickled")  # ingest --n-jobs sends it to workers
    with pytest.raises(AttributeError, match="frozen"):
        view.name = "other"
    copied = pview.model_copy(update={"ingest": pview.ingest.model_copy(update={"checksum": "none"})})
    assert copied.model_dump(mode="json") == params.model_copy(update={"ingest": params.ingest.model_copy(
        update={"checksum": "none"})}).model_dump(mode="json") != params.model_dump(mode="json")


def test_the_hash_is_that_of_the_dump_the_model_gave(tmp_path: Path, _config_snapshots_per_test: Path) -> None:
    """config_hash (every output's provenance) hashes what pydantic's model_dump gave when the snapshot was written,
    not a rebuild of it from the fields, which a serializer added to a model one day would make differ."""
    path = tmp_path / "vehicle.yaml"
    path.write_bytes(DAGON.read_bytes())
    vehicle, _ = snapshot.load_for_ingest(path, None)
    (stored,) = snapshots(_config_snapshots_per_test)
    doc = json.loads(stored.read_text())
    assert doc["vehicle_dump"] == vehicle.model_dump(mode="json")
    doc["vehicle_dump"]["name"] = "as the model dumped it"
    stored.write_text(json.dumps(doc))
    view, _ = snapshot.load_for_ingest(path, None)
    assert view.name == "dagon" and view.model_dump(mode="json")["name"] == "as the model dumped it"


def test_a_trial_with_overrides_gets_the_real_model_with_them_applied(tmp_path: Path) -> None:
    path = overridden_vehicle(tmp_path / "vehicle.yaml")
    vehicle, _ = snapshot.load_for_ingest(path, None)
    view, _ = snapshot.load_for_ingest(path, None)
    assert isinstance(vehicle, Vehicle) and isinstance(view, snapshot.VehicleView)
    assert view.for_trial("trial01") is view  # nothing applies: the view itself
    for trial in ("trial02", "sea3"):
        applied = view.for_trial(trial)
        assert isinstance(applied, Vehicle) and applied.resolve("x") == vehicle.resolve("x")
        assert applied.model_dump(mode="json") == vehicle.for_trial(trial).model_dump(mode="json")
    assert view.for_trial("trial02").streams["nav"].offset_s == 0.25
    assert view.for_trial("sea3").streams["depth"].optional is True
    renamed = view.model_copy(update={"name": "renamed"})  # the real model's copy: overrides and file follow
    assert isinstance(renamed, Vehicle) and renamed.name == "renamed" and renamed.resolve("x") == vehicle.resolve("x")


def test_warnings_of_the_checks_are_given_again(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The default coupled.inputs name DAGON's thrust columns: a vehicle whose thruster is t1 hears it on every
    run, read from the snapshot as well."""
    path = overridden_vehicle(tmp_path / "vehicle.yaml")
    for expected in (Vehicle, snapshot.VehicleView):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            vehicle, _ = snapshot.load_for_ingest(path, PARAMS)
        assert isinstance(vehicle, expected)
        said = [r for r in caplog.records if "coupled.inputs names ['T_th1_N', 'T_th2_N', 'T_th3_N']" in r.message]
        assert len(said) == 1 and said[0].name == "pipeline.config" and str(PARAMS) in said[0].message


def test_warnings_kept_from_a_quiet_run_are_given_by_the_next(tmp_path: Path,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    """``auvid ingest -q`` shows errors only: the run that validates keeps the warning all the same, and a later
    run that shows warnings gives it from the snapshot."""
    path = overridden_vehicle(tmp_path / "vehicle.yaml")
    with caplog.at_level(logging.ERROR):
        assert isinstance(snapshot.load_for_ingest(path, PARAMS)[0], Vehicle)
    assert "coupled.inputs" not in caplog.text  # quiet stays quiet
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert isinstance(snapshot.load_for_ingest(path, PARAMS)[0], snapshot.VehicleView)
    assert caplog.text.count("coupled.inputs names ['T_th1_N', 'T_th2_N', 'T_th3_N']") == 1


def test_other_bytes_other_code_or_a_damaged_snapshot_validate_again(
        tmp_path: Path, _config_snapshots_per_test: Path) -> None:
    path = tmp_path / "vehicle.yaml"
    path.write_bytes(DAGON.read_bytes())
    snapshot.load_for_ingest(path, None)
    assert isinstance(snapshot.load_for_ingest(path, None)[0], snapshot.VehicleView)

    path.write_text(DAGON.read_text(encoding="utf-8").replace("name: dagon", "name: dagon2"), encoding="utf-8")
    vehicle, _ = snapshot.load_for_ingest(path, None)
    assert isinstance(vehicle, Vehicle) and vehicle.name == "dagon2"  # the edit is seen, not the old snapshot
    view, _ = snapshot.load_for_ingest(path, None)
    assert isinstance(view, snapshot.VehicleView) and view.name == "dagon2"

    (stored,) = [p for p in snapshots(_config_snapshots_per_test) if b'"dagon2"' in p.read_bytes()]
    doc = json.loads(stored.read_text())
    code = sorted(doc["code"])
    assert any(f.endswith(("pipeline/config/vehicle.py", "pipeline\\config\\vehicle.py")) for f in code)
    assert any(f.endswith("version.py") and "pydantic" in f for f in code)
    doc["code"][code[0]] = "0" * 64  # as if that source file had changed since
    stored.write_text(json.dumps(doc))
    assert isinstance(snapshot.load_for_ingest(path, None)[0], Vehicle)
    assert isinstance(snapshot.load_for_ingest(path, None)[0], snapshot.VehicleView)  # rewritten

    good = stored.read_text()
    doc = json.loads(good)
    empty = hashlib.sha256(b"").hexdigest()
    damaged = [{**doc, "code": {**doc["code"], "/dev/null": empty}},  # not a regular file: never read, a miss
               {**doc, "warnings": [["pipeline", "not a level"]]}, {**doc, "params": [1]},
               {**doc, "vehicle": {"model": "Vehicle", "fields": [1]}}, {**doc, "overrides": []},
               {**doc, "overrides": {"trial02": {"nav": 1}}}, {**doc, "vehicle_raw": None},
               {**doc, "params_dump": []}, {"format": snapshot.FORMAT}, []]
    deep = "[" * 100_000 + "]" * 100_000  # deeper than the JSON parser recurses
    for damage in ["{not json", "", deep, *map(json.dumps, damaged)]:
        stored.write_text(damage)
        assert isinstance(snapshot.load_for_ingest(path, None)[0], Vehicle), damage[:80]
        assert stored.read_text() == good  # and rewritten

    params = tmp_path / "params.yaml"
    params.write_text("ingest: {checksum: sha256}\n", encoding="utf-8")
    for _ in range(2):
        assert snapshot.load_for_ingest(path, params)[1].ingest.checksum == "sha256"
    params.write_text("ingest: {checksum: none}\n", encoding="utf-8")
    assert snapshot.load_for_ingest(path, params)[1].ingest.checksum == "none"  # the params' bytes count too


def test_the_newest_snapshots_are_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       _config_snapshots_per_test: Path) -> None:
    monkeypatch.setattr(snapshot, "KEEP", 2)
    path = tmp_path / "vehicle.yaml"
    for i in range(4):
        path.write_text(DAGON.read_text(encoding="utf-8").replace("name: dagon", f"name: dagon{i}"), encoding="utf-8")
        snapshot.load_for_ingest(path, None)
        for old in snapshots(_config_snapshots_per_test):  # written seconds apart, whatever the file clock
            if f'"dagon{i}"'.encode() in old.read_bytes():
                os.utime(old, (time.time() - 100 + i,) * 2)
    kept = snapshots(_config_snapshots_per_test)
    assert len(kept) == 2 and {json.loads(p.read_text())["vehicle"]["fields"]["name"] for p in kept} == {
        "dagon2", "dagon3"}
    assert isinstance(snapshot.load_for_ingest(path, None)[0], snapshot.VehicleView)  # the newest one answers
    for name, answered_by in (("dagon2", snapshot.VehicleView), ("dagon4", Vehicle)):  # dagon2 read: kept
        path.write_text(DAGON.read_text(encoding="utf-8").replace("name: dagon", f"name: {name}"), encoding="utf-8")
        assert isinstance(snapshot.load_for_ingest(path, None)[0], answered_by)
    assert {json.loads(p.read_text())["vehicle"]["fields"]["name"] for p in snapshots(_config_snapshots_per_test)} == {
        "dagon2", "dagon4"}


def test_off_or_unwritable_cache_validates_every_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(snapshot.CACHE_ENV, "off")
    assert snapshot.cache_dir() is None
    for _ in range(2):
        assert isinstance(snapshot.load_for_ingest(DAGON, None)[0], Vehicle)
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where the cache directory would be")
    monkeypatch.setenv(snapshot.CACHE_ENV, str(blocked))
    for _ in range(2):
        assert isinstance(snapshot.load_for_ingest(DAGON, None)[0], Vehicle)  # not written, not an error


def test_no_home_directory_validates_every_time(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_home() -> Path:
        raise RuntimeError("Could not determine home directory.")
    monkeypatch.delenv(snapshot.CACHE_ENV)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setattr(Path, "home", no_home)
    assert snapshot.cache_dir() is None
    assert isinstance(snapshot.load_for_ingest(DAGON, None)[0], Vehicle)


def test_a_refused_config_is_refused_every_time(tmp_path: Path, _config_snapshots_per_test: Path) -> None:
    path = tmp_path / "vehicle.yaml"
    path.write_text(DAGON.read_text(encoding="utf-8").replace("name: dagon", "name: 'da gon'"), encoding="utf-8")
    for _ in range(2):
        with pytest.raises(ConfigError, match="name") as err:
            snapshot.load_for_ingest(path, None)
        assert str(path) in str(err.value)
    assert snapshots(_config_snapshots_per_test) == []


PROBE = """
import sys
from pipeline.config import snapshot
vehicle, _ = snapshot.load_for_ingest({path!r}, None)
print(type(vehicle).__name__, vehicle.streams["thrusters"].offset_s)
"""


def test_another_checkout_sharing_the_cache_validates_with_its_own_code(tmp_path: Path) -> None:
    """Two copies of auvid (two checkouts, two environments) with one cache: each answers with what its own code
    validates, never with a snapshot the other wrote. Here the second copy's streams default to another offset."""
    trees = {}
    for name in ("a", "b"):
        trees[name] = tmp_path / name
        shutil.copytree(ROOT / "pipeline", trees[name] / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    sources = trees["b"] / "pipeline" / "config" / "sources.py"
    text = sources.read_text(encoding="utf-8")
    default = 'offset_s: float = Field(0.0, description="Constant offset added to every stamp of this stream.")'
    assert default in text
    sources.write_text(text.replace(default, default.replace("Field(0.0", "Field(0.5")), encoding="utf-8")
    past = time.time() - 60
    os.utime(sources, (past, past))  # edited a minute ago, before the processes below start

    dagon = DAGON.read_text(encoding="utf-8")
    thrusters = dagon.index("\n  thrusters:\n", dagon.index("\nstreams:"))
    vehicle = tmp_path / "vehicle.yaml"  # DAGON with the thrusters' stream at the default offset
    vehicle.write_text(dagon[:thrusters] + dagon[thrusters:].replace("    offset_s: 0.0\n", "", 1), encoding="utf-8")

    def run(tree: str) -> str:
        env = {**os.environ, "PYTHONPATH": str(trees[tree])}
        got = subprocess.run([sys.executable, "-c", PROBE.format(path=str(vehicle))], env=env, cwd=tmp_path,
                             capture_output=True, text=True, timeout=120, check=False)
        assert got.returncode == 0, got.stderr[-3000:]
        return got.stdout.strip()

    assert [run("a"), run("a")] == ["Vehicle 0.0", "VehicleView 0.0"]
    assert [run("b"), run("b")] == ["Vehicle 0.5", "VehicleView 0.5"]
    assert run("a") == "VehicleView 0.0"


def test_a_vehicle_config_from_a_pipe_is_read_once(tmp_path: Path) -> None:
    """``--vehicle /dev/stdin``: the bytes of a pipe can be read only once, so such a config is validated from them
    and no snapshot is kept (reading it again for a snapshot found it empty: a config error)."""
    log = io.write_mcap(tmp_path / "trial01.mcap", io.trial(n=12))
    run = tmp_path / "run"
    for _ in range(2):
        got = subprocess.run([sys.executable, "-m", "pipeline.cli", "ingest", "-q", "--root", str(run),
                              "--vehicle", "/dev/stdin", str(log)], input=yaml.safe_dump(BUDGET_VEHICLE),
                             capture_output=True, text=True, cwd=ROOT, timeout=120, check=False)
        assert got.returncode == 0, got.stderr[-3000:]
        assert (run / "data" / "signals" / "trial01" / "dvl.parquet").exists()


CHANGED_MEANWHILE = """
import pathlib, sys, time
import pipeline.config.loading  # the validators as this process imported them
from pipeline.config import snapshot
sources = pathlib.Path(pipeline.config.loading.__file__).with_name("sources.py")
default = 'offset_s: float = Field(0.0, description="Constant offset added to every stamp of this stream.")'
time.sleep(0.1)
sources.write_text(sources.read_text().replace(default, default.replace("Field(0.0", "Field(0.5")))
vehicle, _ = snapshot.load_for_ingest({path!r}, None)  # validated by the code imported before the edit
print(type(vehicle).__name__, vehicle.streams["thrusters"].offset_s)
"""


def test_code_changed_on_disk_while_a_process_runs_writes_no_snapshot(tmp_path: Path) -> None:
    """A ``git pull`` beside a running notebook: what that process validates is the old code's answer; stored under
    the new files' digests, it would answer a fresh process that runs the new code."""
    tree = tmp_path / "tree"
    shutil.copytree(ROOT / "pipeline", tree / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    dagon = DAGON.read_text(encoding="utf-8")
    thrusters = dagon.index("\n  thrusters:\n", dagon.index("\nstreams:"))
    vehicle = tmp_path / "vehicle.yaml"
    vehicle.write_text(dagon[:thrusters] + dagon[thrusters:].replace("    offset_s: 0.0\n", "", 1), encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(tree)}

    def run(code: str) -> str:
        got = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                             timeout=120, check=False)
        assert got.returncode == 0, got.stderr[-3000:]
        return got.stdout.strip()

    assert run(CHANGED_MEANWHILE.format(path=str(vehicle))) == "Vehicle 0.0"
    # the guard: the next process validates with the new code, never reads what the old code validated (0.0)
    probes = [run(PROBE.format(path=str(vehicle))) for _ in range(3)]
    assert probes[0] == "Vehicle 0.5", probes
    # and snapshots still work after it: a later process reads one (a busy CI machine once made the first probe
    # write none, cause not found; the guard above is what this test is for)
    assert "VehicleView 0.5" in probes[1:] and all(p.endswith(" 0.5") for p in probes), probes
