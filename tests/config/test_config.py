from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline.config import Params, Vehicle, config_hash, load_params, load_vehicle, write_schemas
from pipeline.errors import ConfigError
from pipeline.units import conversion

ROOT = Path(__file__).resolve().parents[2]


def test_schemas_in_repo_are_generated_from_code(tmp_path: Path) -> None:
    for path in write_schemas(tmp_path):
        committed = ROOT / "schemas" / path.name
        assert committed.exists(), f"{committed} missing: run python -m pipeline.config"
        assert json.loads(committed.read_text()) == json.loads(path.read_text()), (
            f"{committed.name} is stale: run python -m pipeline.config")


def test_unknown_key_names_key_and_file(tmp_path: Path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text("sync:\n  rate_hz: 20\n  ratehz: 10\n")
    with pytest.raises(ConfigError) as info:
        load_params(path)
    assert str(path) in str(info.value)
    assert "sync.ratehz" in str(info.value)


def test_bad_value_names_key(tmp_path: Path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text("sync:\n  rate_hz: -1\n")
    with pytest.raises(ConfigError, match="sync.rate_hz"):
        load_params(path)


def test_missing_file_and_directory_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_vehicle(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="directory"):
        load_vehicle(tmp_path)


def test_params_defaults_and_hash_stable() -> None:
    assert load_params(None) == Params()
    assert config_hash(Params()) == config_hash(Params())
    assert config_hash(Params()) != config_hash(Params(sync={"rate_hz": 10}))


@pytest.mark.parametrize(
    ("signal", "unit", "raw", "expected"),
    [
        ("r_fog_radps", "deg/s", 180.0, 3.141592653589793),
        ("u_dvl_mps", "mm/s", 250.0, 0.25),
        ("n1_rpm", "rev/s", 2.0, 120.0),
        ("n1_rpm", "rad/s", 2 * 3.141592653589793, 60.0),
        ("depth_m", None, 3.5, 3.5),
        ("p_Pa", "bar", 1.5, 150000.0),
    ],
)
def test_unit_conversion_to_suffix_unit(signal: str, unit: str | None, raw: float, expected: float) -> None:
    conv = conversion(signal, unit)
    assert raw * conv.factor + conv.offset == pytest.approx(expected, rel=1e-12)


def test_unit_dimension_mismatch_and_missing_suffix() -> None:
    with pytest.raises(ConfigError, match="is a angle"):
        conversion("u_dvl_mps", "deg")
    with pytest.raises(ConfigError, match="unit suffix"):
        conversion("u_dvl", None)


def test_vehicle_rejects_unknown_speed_signal() -> None:
    stream = {"topic": "/t", "clock": "log", "signals": {"n1_rpm": {"field": "data"}}}
    base = {
        "name": "v",
        "rigid_body": {"mass_kg": 10, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": "t1", "speed_signal": "n9_rpm", "position_m": [0, 0, 0],
                       "direction": [1, 0, 0], "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
        "sensors": {"dvl": {"velocity": ["a_mps", "b_mps", "c_mps"]}, "attitude": {"yaw": "yaw_rad"}},
        "streams": {"th": stream},
    }
    with pytest.raises(Exception, match="n9_rpm"):
        Vehicle.model_validate(base)
