"""Vehicle numbers bounded by what they mean (issue 36, item 3): each case starts from the example vehicle, changes
one thing, and must be refused at load with the file and the key named and the accepted range said."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from pipeline.config import load_vehicle
from pipeline.config.sources import CsvOptions, TimeOptions
from tests.config.test_config_refuses import BASE, Edit, _refused, _write, add_csv_stream, put

CASES = [
    pytest.param(put("streams.fog.time", {"rate_hz": 1e-300}), "streams.fog.time.rate_hz", "0.001 to 1e+09 Hz",
                 id="rate-1e-300"),
    pytest.param(put("streams.fog.time", {"rate_hz": 1e12}), "streams.fog.time.rate_hz", "0.001 to 1e+09 Hz",
                 id="rate-1e12"),
    pytest.param(put("thrusters.0.position_m", [1e9, 0.0, 0.0]), "thrusters.0.position_m", "within 1000 m",
                 id="thruster-1e9-m"),
    pytest.param(put("sensors.dvl.position_m", [0.0, -2e3, 0.0]), "sensors.dvl.position_m", "within 1000 m",
                 id="dvl-2km"),
    pytest.param(put("rigid_body.cb_m", [0.0, 0.0, 1e6]), "rigid_body.cb_m", "within 1000 m", id="cb-1e6-m"),
    pytest.param(put("rigid_body.mass_kg", 1e-300), "rigid_body.mass_kg", "0.001 to 1e+08 kg", id="mass-1e-300"),
    pytest.param(put("rigid_body.mass_kg", 1e12), "rigid_body.mass_kg", "0.001 to 1e+08 kg", id="mass-1e12"),
    pytest.param(add_csv_stream(encoding="rot13"), "streams.tank.csv.encoding", "not a text encoding", id="rot13"),
    pytest.param(add_csv_stream(encoding="base64"), "streams.tank.csv.encoding", "not a text encoding", id="base64"),
    pytest.param(add_csv_stream(encoding="hex"), "streams.tank.csv.encoding", "not a text encoding", id="hex"),
    pytest.param(add_csv_stream(encoding="zlib"), "streams.tank.csv.encoding", "not a text encoding", id="zlib"),
    # loaded, then nonsense or a traceback at their stage (issue 36, item 3)
    pytest.param(put("rigid_body.gravity_mps2", 3.7e275), "rigid_body.gravity_mps2", "less than or equal to 100",
                 id="gravity-3.7e275"),
    pytest.param(put("rigid_body.gravity_mps2", 1e-300), "rigid_body.gravity_mps2", "greater than or equal to 0.1",
                 id="gravity-1e-300"),
    pytest.param(put("rigid_body.buoyancy_N", 1e300), "rigid_body.buoyancy_N", "more than 10 times the weight",
                 id="buoyancy-1e300"),
    pytest.param(put("sensors.dvl.rotation_rpy_deg", [0.0, 0.0, 1e261]), "sensors.dvl.rotation_rpy_deg",
                 "within +/-360 deg", id="dvl-rotation-1e261"),
    pytest.param(put("sensors.rates.signs", [1.0, 1e300, 1.0]), "sensors.rates.signs", "1 or -1",
                 id="rate-sign-1e300"),
    pytest.param(put("thrusters.0.lag_s", 1e300), "thrusters.0.lag_s", "less than or equal to 60", id="lag-1e300"),
    pytest.param(put("thrusters.0.thrust.k_fwd_N_per_rpm2", 1e300), "thrusters.0.thrust.k_fwd_N_per_rpm2",
                 "less than or equal to 10000", id="thrust-k-1e300"),
    pytest.param(put("streams.dvl.signals.dvl_x_mps.scale", 1e-300), "streams.dvl.signals.dvl_x_mps.scale",
                 "size 1e-12 to 1e+12", id="scale-1e-300"),
    pytest.param(put("streams.dvl.signals.dvl_x_mps.scale", -1e300), "streams.dvl.signals.dvl_x_mps.scale",
                 "size 1e-12 to 1e+12", id="scale-minus-1e300"),
]


@pytest.mark.parametrize(("edit", "field", "says"), CASES)
def test_vehicle_number_out_of_its_range_is_refused(tmp_path: Path, edit: Edit, field: str, says: str) -> None:
    doc = copy.deepcopy(BASE)
    edit(doc)
    err = _refused(load_vehicle, _write(tmp_path, yaml.safe_dump(doc, sort_keys=False)))
    assert err.field is not None and err.field.startswith(field), f"field {err.field!r}, expected {field!r}: {err}"
    assert says in str(err), f"{says!r} not in: {err}"


def test_the_bounds_admit_what_vehicles_have(tmp_path: Path) -> None:
    """A 20 g micro robot, a 5e7 kg submarine, a sensor 150 m aft, slow and fast loggers, text codecs."""
    doc = copy.deepcopy(BASE)
    put("thrusters.0.position_m", [-150.0, 0.0, 0.0])(doc)
    put("streams.fog.time", {"rate_hz": 1 / 60})(doc)
    add_csv_stream(encoding="utf-16")(doc)
    assert load_vehicle(_write(tmp_path, yaml.safe_dump(doc))).streams["fog"].time.rate_hz == 1 / 60
    for rate in (1e-3, 1.0, 1e6, 1e9):
        assert TimeOptions(rate_hz=rate).rate_hz == rate
    for encoding in ("utf-8", "cp1252", "latin-1", "utf-16-le", "utf-32"):
        assert CsvOptions(time_column="t", encoding=encoding).encoding == encoding
