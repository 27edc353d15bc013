"""`auvid init`: a starter config from the example's logs, TODOs that the loader names, and, with the constants
filled in, the example's features reproduced exactly."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import yaml

from pipeline import cli
from pipeline.cli.init import starter_config
from pipeline.config import Params, load_vehicle, todo_markers
from pipeline.errors import ConfigError
from pipeline.sim import generate_trial, load_example_vehicle, write_trial
from pipeline.store import PART_FILE, partition_dir
from pipeline.tableio import read_parquet
from stages.common import run_stages

STAGES = ["ingest", "sync", "differentiate", "derive", "features"]


@pytest.fixture(scope="module")
def example_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    trial = generate_trial(load_example_vehicle(), duration_s=25.0, seed=3, warmup_s=2.0)
    return write_trial(trial, "mcap", tmp_path_factory.mktemp("logs") / "trial01.mcap")


def _get(doc: Any, key: str) -> Any:
    for part in key.split("."):
        doc = doc[int(part)] if isinstance(doc, list) else doc[part]
    return doc


def _set(doc: Any, key: str, value: Any) -> None:
    *head, last = key.split(".")
    for part in head:
        doc = doc[int(part)] if isinstance(doc, list) else doc[part]
    doc[int(last) if isinstance(doc, list) else last] = value


def filled(text: str) -> dict[str, Any]:
    """The starter with every TODO taken from the example vehicle at the same key, and the clock offsets of the
    streams whose topic and clock agree with the example's (the rest: offset 0, see the test)."""
    doc = yaml.safe_load(text)
    example = load_example_vehicle().model_dump(mode="json")
    for key, _ in todo_markers(doc):
        _set(doc, key, _get(example, key))
    by_topic = {s["topic"]: s for s in example["streams"].values()}
    for stream in doc["streams"].values():
        theirs = by_topic[stream["topic"]]
        if theirs["clock"] == stream["clock"]:
            stream["offset_s"] = theirs["offset_s"]
    return doc


def test_starter_recognises_the_example_topics(example_log: Path) -> None:
    starter = starter_config([example_log])
    doc = yaml.safe_load(starter.text)
    streams = {s["topic"]: s for s in doc["streams"].values()}
    assert set(streams) == {"/ahrs/imu", "/fog/rate", "/pressure/depth", "/dvl/data", "/thrusters/joint_states"}
    assert [t["name"] for t in doc["thrusters"]] == ["th1", "th2", "th3", "th4", "th5"]
    assert streams["/thrusters/joint_states"]["signals"]["n3_rpm"] == {"field": "velocity[name=th3]",
                                                                      "unit": "rad/s"}
    assert doc["sensors"]["dvl"]["velocity"] == ["dvl_x_mps", "dvl_y_mps", "dvl_z_mps"]
    assert doc["sensors"]["dvl"]["valid"] == "dvl_valid_flag"
    assert doc["sensors"]["rates"] == {"p": "p_ahrs_radps", "q": "q_ahrs_radps", "r": "r_fog_radps"}
    assert all(s["clock"] == "header" for s in streams.values())  # every type has a header, every stamp sane
    keys = [k for k, _ in todo_markers(doc)]
    assert "rigid_body.mass_kg" in keys and "thrusters.4.thrust" in keys and "sensors.dvl.position_m" in keys
    assert starter.todo_count == len(keys)


def test_loading_the_starter_lists_what_is_left(tmp_path: Path, example_log: Path) -> None:
    path = tmp_path / "vehicle.yaml"
    path.write_text(starter_config([example_log]).text)
    with pytest.raises(ConfigError) as err:
        load_vehicle(path)
    text = str(err.value)
    assert "still to fill in" in text
    for key in ("rigid_body.mass_kg", "added_mass", "thrusters.2.direction", "sensors.attitude.convention",
                "sensors.dvl.rotation_rpy_deg"):
        assert f"{key}: " in text
    doc = filled(path.read_text())
    doc["rigid_body"]["mass_kg"] = "TODO: mass"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=r"1 value\(s\) still to fill in \(TODO\): rigid_body.mass_kg: mass"):
        load_vehicle(path)


def test_header_stamps_of_zero_choose_log_clock(tmp_path: Path) -> None:
    trial = generate_trial(load_example_vehicle(), duration_s=3.0, seed=0)
    fog = trial.streams["fog"]
    fog.header_ns[:] = 0
    log = write_trial(trial, "mcap", tmp_path / "zero.mcap")
    doc = yaml.safe_load(starter_config([log]).text)
    clocks = {s["topic"]: s["clock"] for s in doc["streams"].values()}
    assert clocks["/fog/rate"] == "log" and clocks["/ahrs/imu"] == "header"
    assert "header stamps unusable (zero)" in starter_config([log]).text


def test_init_reproduces_the_example_features(tmp_path: Path, example_log: Path) -> None:
    out = tmp_path / "starter.yaml"
    assert cli.main(["init", str(example_log), "-o", str(out), "--name", "dagon"]) == 0
    filled_path = tmp_path / "filled.yaml"
    filled_path.write_text(yaml.safe_dump(filled(out.read_text()), sort_keys=False))
    params = Params.model_validate({"sync": {"rate_hz": 10.0, "min_segment_s": 5.0}})
    frames = []
    for name, vehicle in (("example", load_example_vehicle()), ("init", load_vehicle(filled_path))):
        root = tmp_path / name
        results = run_stages(root, vehicle, params, STAGES, logs=[example_log])
        assert not any(r.quarantined for r in results)
        frames.append(read_parquet(partition_dir(root, vehicle.name, "trial01") / PART_FILE)[0].to_pandas())
    example, starter = frames
    assert len(example) > 100
    pd.testing.assert_frame_equal(starter, example, check_exact=True)


def test_odometry_twist_is_written_as_flu(tmp_path: Path) -> None:
    """A nav_msgs/Odometry twist is FLU (ROS): init writes ``axes: flu`` and the rates' signs [1, -1, -1], the
    sensors section test_odometry_source checks against the true FRD motion."""
    from tests.estimation.test_odometry_source import VEHICLE, write_bag

    doc = yaml.safe_load(starter_config([write_bag(tmp_path / "run01")]).text)
    sensors = doc["sensors"]
    odom = next(name for name, s in doc["streams"].items() if s["topic"] == "/odom")
    known = yaml.safe_load(VEHICLE)["sensors"]
    assert odom == "odom"
    assert sensors["velocity"] == known["velocity"]
    assert sensors["rates"] == known["rates"]


def test_init_on_a_text_log_is_a_usage_error_pointing_to_inspect(tmp_path: Path, capsys) -> None:
    """`auvid init` reads ROS logs only: a CSV gets exit 2 and the way forward, not a traceback."""
    log = tmp_path / "run01.csv"
    log.write_text("t,x\n0.0,1.0\n0.1,1.5\n0.2,2.0\n")
    assert cli.main(["init", str(log), "-o", str(tmp_path / "v.yaml")]) == 2
    err = capsys.readouterr().err
    assert "run01.csv" in err and "auvid inspect" in err and "Traceback" not in err
    assert not (tmp_path / "v.yaml").exists()
