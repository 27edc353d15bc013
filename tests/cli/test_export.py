"""`auvid export`: one MCAP per trial, read back with the mcap reader, every documented channel, values = Parquet."""

from __future__ import annotations

import io
import json
import math
import re
from pathlib import Path
from typing import Any

import joblib
import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import NonSeekingReader, SeekingReader
from sklearn.linear_model import LinearRegression

from pipeline import cli, export
from pipeline.cli import common as cli_common
from pipeline.config import Params
from pipeline.models.card import load_model, save_model
from stages import decoupled as decoupled_stage
from stages import simulate as simulate_stage
from tests.studies.helpers import build_store

REPO = Path(__file__).resolve().parents[2]
PARAMS = Params(
    features={"test_trials": ["test"]},
    decoupled={"models": ["ls", "gp"], "max_samples": 60, "gp_max_samples": 60, "curve_points": 2, "folds": 2},
    simulate={"band_samples": 4, "outage_windows_s": [5.0]},
)
COUPLED_IN = ["u_mps", "v_mps", "r_radps", "n1_rpm", "n2_rpm"]
COUPLED_OUT = ["udot_mps2", "vdot_mps2", "rdot_radps2"]


@pytest.fixture(scope="module")
def run_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two short simulated trials through ingest ... simulate, and one carded coupled model."""
    root = tmp_path_factory.mktemp("export_run")
    vehicle, _ = build_store(root, {"a": ("all", 21, 15.0, True), "test": ("all", 22, 15.0, False)}, PARAMS)
    decoupled_stage.run(root, vehicle, PARAMS)
    derived = pq.read_table(root / "data/derived/a.parquet").to_pandas().dropna(subset=COUPLED_IN + COUPLED_OUT)
    lin = LinearRegression().fit(derived[COUPLED_IN].to_numpy(), derived[COUPLED_OUT].to_numpy())
    save_model(lin, root / "data/models/coupled/lin.joblib", {"inputs": COUPLED_IN, "outputs": COUPLED_OUT})
    simulate_stage.run(root, vehicle, PARAMS)
    return root


@pytest.fixture(scope="module")
def exported(run_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("mcap")
    results = export.export_trials(run_root, out_dir=out)
    return {"out": out, "results": {r.trial: r for r in results}}


def _read(path: Path, seeking: bool = True) -> tuple[dict[str, Any], dict[str, list[tuple[int, dict]]], Any]:
    data = path.read_bytes()
    reader = SeekingReader(io.BytesIO(data)) if seeking else NonSeekingReader(io.BytesIO(data))
    channels, messages = {}, {}
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        channels[channel.topic] = (schema, channel)
        messages.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    return channels, messages, reader


def _documented_topics() -> list[str]:
    text = (REPO / "docs/user-guide.md").read_text()
    section = text.split("auvid export`", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `(/auvid/[^`]+)` \|", section, flags=re.M)


def _same(a: Any, b: float) -> bool:
    return (a is None and not math.isfinite(b)) or (a is not None and math.isclose(a, b, rel_tol=1e-12,
                                                                                   abs_tol=1e-15))


def test_the_documented_channels_are_the_module_s(exported: dict[str, Any]) -> None:
    assert _documented_topics() == list(export.TOPICS)


@pytest.mark.parametrize("seeking", [True, False], ids=["seeking", "streaming"])
def test_every_documented_channel_is_in_the_test_trial(exported: dict[str, Any], seeking: bool) -> None:
    channels, messages, _ = _read(exported["out"] / "test.mcap", seeking)
    models = {"coupled": ["lin"], "decoupled": ["gp", "ls"], "free_run": ["coupled_lin", "gp", "ls"]}
    expected = set()
    for topic in export.TOPICS:
        if "<model>" in topic:
            kind = topic.split("/")[-2]
            expected |= {topic.replace("<model>", m) for m in models["free_run" if kind == "free_run" else kind]}
        else:
            expected.add(topic)
    assert set(channels) == expected
    for schema, channel in channels.values():
        assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
        doc = json.loads(schema.data)
        assert doc["type"] == "object" and "t_ns" in doc["properties"]
    assert exported["results"]["test"].messages == {t: len(m) for t, m in messages.items()}


def test_messages_follow_their_schema_and_are_stamped_in_log_time(run_root: Path, exported: dict[str, Any]) -> None:
    channels, messages, _ = _read(exported["out"] / "test.mcap")
    kinds = {"number": (int, float), "integer": int, "boolean": bool, "string": str, "object": dict}
    for topic, msgs in messages.items():
        props = json.loads(channels[topic][0].data)["properties"]
        for log_time, msg in msgs:
            assert msg["t_ns"] == log_time and set(msg) == set(props)
            for key, value in msg.items():
                types = props[key]["type"]
                types = [types] if isinstance(types, str) else types
                assert value is None and "null" in types or isinstance(value, tuple(kinds[t] for t in types
                                                                                    if t != "null")), (topic, key)
                if isinstance(value, dict):
                    assert set(value) == set(props[key]["properties"])
        stamps = [t for t, _ in msgs]
        assert stamps == sorted(stamps)
    data = (exported["out"] / "test.mcap").read_bytes()
    in_file = [m.log_time for _, _, m in NonSeekingReader(io.BytesIO(data)).iter_messages(log_time_order=False)]
    assert in_file == sorted(in_file)  # the file itself is in time order across channels (no reader sorting)
    synced = pq.read_table(run_root / "data/synced/test.parquet")
    assert [t for t, _ in messages["/auvid/synced"]] == synced.column("t_ns").to_pylist()


def test_flat_channels_equal_their_parquet(run_root: Path, exported: dict[str, Any]) -> None:
    _, messages, _ = _read(exported["out"] / "test.mcap")
    for topic, rel in (("/auvid/synced", "data/synced/test.parquet"),
                       ("/auvid/kinematics", "data/kinematics/test.parquet")):
        table = pq.read_table(run_root / rel)
        rows = [m for _, m in messages[topic]]
        assert len(rows) == table.num_rows
        for name in table.column_names:
            column = table.column(name).to_pylist()
            got = [r[name] for r in rows]
            if isinstance(column[0], float):
                assert all(_same(g, c) for g, c in zip(got, column, strict=True)), (topic, name)
            else:
                assert got == column, (topic, name)


def test_velocity_and_acceleration_bands(run_root: Path, exported: dict[str, Any]) -> None:
    _, messages, _ = _read(exported["out"] / "test.mcap")
    kin = pq.read_table(run_root / "data/kinematics/test.parquet").to_pandas()
    vel = [m for _, m in messages["/auvid/velocity"]]
    acc = [m for _, m in messages["/auvid/acceleration"]]
    assert set(vel[0]) == {"t_ns", "u", "v", "w", "p", "q", "r"}
    for i in (0, len(kin) // 2, len(kin) - 1):
        est, sd, meas = (float(kin[c].iloc[i]) for c in ("u_smooth_mps", "u_smooth_std_mps", "u_meas_mps"))
        got = dict(vel[i]["u"])
        assert _same(got.pop("measured"), meas)
        assert got == pytest.approx({"estimate": est, "sd": sd, "lower": est - 2 * sd, "upper": est + 2 * sd})
        a, s = kin["rdot_radps2"].iloc[i], kin["rdot_std_radps2"].iloc[i]
        assert acc[i]["r"] == pytest.approx({"estimate": a, "sd": s, "lower": a - 2 * s, "upper": a + 2 * s})
    assert all(m["u"]["lower"] <= m["u"]["estimate"] <= m["u"]["upper"] for m in vel if m["u"]["sd"] is not None)


def test_predictions_are_the_carded_models_on_the_derived_rows(run_root: Path, exported: dict[str, Any]) -> None:
    _, messages, _ = _read(exported["out"] / "test.mcap")
    derived = pq.read_table(run_root / "data/derived/test.parquet").to_pandas()
    lin, _ = load_model(run_root / "data/models/coupled/lin.joblib")
    rows = [m for _, m in messages["/auvid/prediction/coupled/lin"]]
    ok = derived[COUPLED_IN].notna().all(axis=1).to_numpy()
    want = lin.predict(derived.loc[ok, COUPLED_IN].to_numpy())
    got = np.array([[r[c]["predicted"] for c in COUPLED_OUT] for r, keep in zip(rows, ok, strict=True) if keep])
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert [r["udot_mps2"]["measured"] for r in rows] == pytest.approx(derived["udot_mps2"].tolist(), nan_ok=True)
    ls_u, _ = load_model(run_root / "data/models/decoupled/u_ls.joblib")
    rows = [m for _, m in messages["/auvid/prediction/decoupled/ls"]]
    assert set(rows[0]) == {"t_ns", "d_u_N", "d_v_N", "d_r_Nm"}
    want = ls_u.predict(derived[["u_mps"]].to_numpy())
    np.testing.assert_allclose([r["d_u_N"]["predicted"] for r in rows], want, rtol=1e-12)
    assert [r["d_u_N"]["measured"] for r in rows] == pytest.approx(derived["d_u_N"].tolist())


def test_free_runs_equal_the_simulate_stage_s_parquet(run_root: Path, exported: dict[str, Any]) -> None:
    _, messages, _ = _read(exported["out"] / "test.mcap")
    table = pq.read_table(run_root / "data/simulation/test/free_run.parquet").to_pandas()
    gp = [m for _, m in messages["/auvid/free_run/gp"]]
    assert set(gp[0]["u_mps"]) == {"predicted", "measured", "lower", "upper"}
    for key, col in (("predicted", "gp/u_mps"), ("lower", "gp/u_mps/lower"), ("upper", "gp/u_mps/upper"),
                     ("measured", "u_mps")):
        assert all(_same(m["u_mps"][key], v) for m, v in zip(gp, table[col], strict=True)), key
    assert set([m for _, m in messages["/auvid/free_run/ls"]][0]["r_radps"]) == {"predicted", "measured"}
    assert any(m["u_mps"]["predicted"] is not None for m in gp)


def test_training_trial_has_no_free_run(exported: dict[str, Any]) -> None:
    channels, _, _ = _read(exported["out"] / "a.mcap")
    assert not [t for t in channels if t.startswith("/auvid/free_run/")]
    assert "/auvid/prediction/coupled/lin" in channels


def test_same_inputs_same_bytes_and_no_temp_file(run_root: Path, exported: dict[str, Any], tmp_path: Path) -> None:
    again = export.export_trials(run_root, ["test"], tmp_path)[0]
    assert again.path.read_bytes() == (exported["out"] / "test.mcap").read_bytes()
    assert [p.name for p in tmp_path.iterdir()] == ["test.mcap"]
    assert again.path.stat().st_mode & 0o777 == 0o644


def test_a_failed_export_leaves_the_old_file(run_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    old = export.export_trials(run_root, ["test"], tmp_path)[0].path.read_bytes()

    def crash(stream: Any, *args: Any) -> None:
        stream.write(b"\x89MCAP0\r\n half")
        raise RuntimeError("disk full")

    monkeypatch.setattr(export, "_write", crash)
    with pytest.raises(RuntimeError):
        export.export_trials(run_root, ["test"], tmp_path)
    assert (tmp_path / "test.mcap").read_bytes() == old and [p.name for p in tmp_path.iterdir()] == ["test.mcap"]


def test_an_uncarded_model_is_never_loaded(run_root: Path, tmp_path: Path) -> None:
    class Payload:
        def __reduce__(self) -> tuple[object, tuple[str, str]]:
            return (open, (str(tmp_path / "pwned"), "w"))

    stray = run_root / "data/models/decoupled/u_evil.joblib"
    joblib.dump(Payload(), stray)
    try:
        export.export_trials(run_root, ["test"], tmp_path / "out")
    finally:
        stray.unlink()
    assert not (tmp_path / "pwned").exists()


def test_a_carded_model_the_params_do_not_name_is_never_loaded(run_root: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """A model file with a valid card that the run did not fit (an earlier run's, one copied in): not unpickled."""
    class Payload:
        def __reduce__(self) -> tuple[object, tuple[str, str]]:
            return (open, (str(tmp_path / "pwned"), "w"))

    stray = run_root / "data/models/decoupled/u_evil.joblib"
    written = save_model(Payload(), stray, {"inputs": ["u_mps"], "outputs": ["d_u_N"], "model": "evil"})
    try:
        results = export.export_trials(run_root, ["test"], tmp_path / "out", models=export.named_models(PARAMS))
        assert cli.main(["export", str(run_root), "--trial", "test", "--out", str(tmp_path / "cli"), "-q"]) == 0
    finally:
        for path in written:
            path.unlink()
    assert not (tmp_path / "pwned").exists()
    skipped = results[0].skipped
    assert "decoupled model u_evil.joblib: not named by the run's params (decoupled.models)" in skipped
    assert "coupled model lin.joblib: not named by the run's params (coupled.models)" in skipped
    assert {"/auvid/prediction/decoupled/ls", "/auvid/prediction/decoupled/gp"} <= set(results[0].messages)
    assert not any("evil" in topic or "coupled/lin" in topic for topic in results[0].messages)


def test_cli(run_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["export", str(run_root), "--trial", "test", "--out", str(tmp_path), "-q"]) == cli_common.EXIT_OK
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and out.startswith("auvid export: done (exit 0): 1 trial(s)")
    assert [p.name for p in tmp_path.iterdir()] == ["test.mcap"]
    assert cli.main(["export", str(run_root), "--trial", "nope"]) == cli_common.EXIT_USAGE
    assert "no synced table for trial(s) ['nope']; available: ['a', 'test']" in capsys.readouterr().err
    assert cli.main(["export", str(tmp_path)]) == cli_common.EXIT_USAGE
    assert "nothing to export" in capsys.readouterr().err
    assert cli.main(["export", str(tmp_path / "missing")]) == cli_common.EXIT_USAGE
