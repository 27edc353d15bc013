"""Per-signal ``sign`` and ``scale`` (issue 34, item 3): a sensor's own convention mapped onto the pipeline's, once,
at ingest, before the unit conversion: the signal is ``unit(sign * scale * raw)``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pipeline.config import Vehicle, load_vehicle, parse
from pipeline.errors import ConfigError
from pipeline.ingest import ingest_log

T0_MS = 1_700_000_000_000
#: ArduSub-like altitude relative to the surface, positive up, in counts of 2 mm (asymmetric on purpose: a sign
#: forgotten or a scale applied after the unit both give other numbers)
REL_ALT = np.array([-1000.0, -1250.0, 40.0, -3.0, 0.0])


def _vehicle(depth: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {
        "name": "testbot",
        "rigid_body": {"mass_kg": 10, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": "t1", "speed_signal": "n1_rpm", "position_m": [0, 0, 0], "direction": [1, 0, 0],
                       "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
        "sensors": {"velocity": {"frame": "body", "signals": ["u_mps", "v_mps"]}, "attitude": {"yaw": "yaw_rad"},
                    "depth": "depth_m"},
        "streams": {"nav": {"file": "nav.csv", "clock": "column", "csv": {"time_column": "t", "time_unit": "ms"},
                            "signals": {"u_mps": {"field": "u"}, "v_mps": {"field": "v"},
                                        "yaw_rad": {"field": "yaw", "unit": "deg", "sign": -1},
                                        "n1_rpm": {"field": "n1"}, "depth_m": depth}}},
        **extra,
    }


def _trial(directory: Path) -> Path:
    directory.mkdir(parents=True)
    rows = [f"{T0_MS + 100 * i},0.5,0,{10 * i},900,{alt}\n" for i, alt in enumerate(REL_ALT)]
    (directory / "nav.csv").write_text("t,u,v,yaw,n1,alt\n" + "".join(rows))
    return directory


def test_sign_and_scale_come_before_the_unit(tmp_path: Path) -> None:
    v = parse(Vehicle, _vehicle({"field": "alt", "sign": -1, "scale": 2, "unit": "mm"}))
    out = ingest_log(_trial(tmp_path / "dive01"), v)
    nav = out.tables["nav"]
    # depth (down) = -(2 mm * counts up) = -0.002 m * counts
    np.testing.assert_allclose(nav["depth_m"].to_numpy(), [2.0, 2.5, -0.08, 0.006, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(nav["yaw_rad"].to_numpy(), -np.deg2rad(10.0 * np.arange(5)), rtol=1e-12)
    np.testing.assert_allclose(nav["u_mps"].to_numpy(), 0.5)  # the others as they are


def test_a_trial_override_flips_one_dive(tmp_path: Path) -> None:
    """A sensor mounted the other way in one dive: the override's signal replaces the stream's (sign and all)."""
    trials = {"trials": {"dive02": {"streams": {"nav": {"signals": {"depth_m": {"field": "alt", "unit": "mm"}}}}}}}
    v = parse(Vehicle, _vehicle({"field": "alt", "sign": -1, "unit": "mm"}, **trials))
    one = ingest_log(_trial(tmp_path / "dive01"), v).tables["nav"]["depth_m"].to_numpy()
    two = ingest_log(_trial(tmp_path / "dive02"), v).tables["nav"]["depth_m"].to_numpy()
    np.testing.assert_allclose(one, -REL_ALT / 1000)
    np.testing.assert_allclose(two, REL_ALT / 1000)


@pytest.mark.parametrize(("depth", "key", "message"), [
    ({"field": "alt", "scale": 0}, "streams.nav.signals.depth_m.scale", "finite, non-zero"),
    ({"field": "alt", "scale": ".nan"}, "streams.nav.signals.depth_m.scale", "finite"),
    ({"field": "alt", "scale": "-.inf"}, "streams.nav.signals.depth_m.scale", "finite"),
    ({"field": "alt", "sign": 2}, "streams.nav.signals.depth_m.sign", "1 or -1"),
    ({"field": "alt", "sign": -0.5}, "streams.nav.signals.depth_m.sign", "1 or -1"),
    ({"field": "alt", "sign": True}, "streams.nav.signals.depth_m.sign", "boolean"),
])
def test_bad_sign_or_scale_names_the_key(tmp_path: Path, depth: dict[str, Any], key: str, message: str) -> None:
    import yaml

    text = yaml.safe_dump(_vehicle(depth)).replace("'.nan'", ".nan").replace("'-.inf'", "-.inf")
    path = tmp_path / "vehicle.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as err:
        load_vehicle(path)
    assert err.value.field == key and str(path) in str(err.value)


def test_a_quaternion_takes_no_sign() -> None:
    doc = _vehicle({"field": "alt"})
    doc["streams"]["nav"]["signals"]["att_quat"] = {"field": "q", "sign": -1}
    with pytest.raises(ConfigError, match="quaternion") as err:
        parse(Vehicle, doc)
    assert err.value.field == "streams.nav.signals.att_quat.sign"
