"""User message definitions (issue 14, item 3): a ROS 2 sqlite3 bag without definitions decodes with `.msg` files.

The bags are written by rosbags' own writer: `mavros_msgs/msg/OverrideRCIn` (thruster PWM, not a ROS 2 standard
type) and the header-less `std_msgs/msg/Float64`, either with the empty definitions a recorder writes for a type it
does not know, or with no `message_definitions` table at all (bags before Iron).
"""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.config import Vehicle, load_vehicle
from pipeline.errors import ConfigError
from pipeline.ingest import ingest_log
from pipeline.io import open_log
from pipeline.io.msgdefs import load_user_types, msgtype_of
from tests.io.helpers import OVERRIDE_RC_IN

RC = "mavros_msgs/msg/OverrideRCIn"
FLOAT64 = "std_msgs/msg/Float64"
T0_NS = 1_700_000_000_000_000_000
N = 25


def pwm(i: int) -> np.ndarray:
    """The 18 channels of message ``i``: thruster PWM around 1500 us, the rest released (0) or unchanged."""
    ch = np.zeros(18, dtype=np.uint16)
    ch[0] = 1500 + 10 * i
    ch[1] = 1500 - 7 * i
    ch[5] = 1100 + i
    ch[17] = 65535
    return ch


def write_bag(path: Path, *, definitions: str) -> Path:
    """A sqlite3 bag of N OverrideRCIn (20 Hz) and N Float64 depths; ``definitions``: 'empty' or 'none'."""
    from rosbags.rosbag2 import Writer

    store = get_typestore(Stores.LATEST)
    store.register(get_types_from_msg(OVERRIDE_RC_IN, RC))
    no_hash = "RIHS01_" + "0" * 64
    with Writer(path, version=9) as w:
        rc = w.add_connection("/mavros/rc/override", RC, msgdef="", rihs01=no_hash)
        depth = w.add_connection("/bluerov/depth", FLOAT64, msgdef="", rihs01=no_hash)
        for i in range(N):
            msg = store.types[RC](channels=pwm(i))
            w.write(rc, T0_NS + i * 50_000_000, bytes(store.serialize_cdr(msg, RC)))
            d = store.types[FLOAT64](data=0.5 + 0.01 * i)
            w.write(depth, T0_NS + i * 50_000_000 + 7, bytes(store.serialize_cdr(d, FLOAT64)))
    db = next(path.glob("*.db3"))
    con = sqlite3.connect(db)
    try:
        assert {r[0] for r in con.execute("SELECT encoded_message_definition FROM message_definitions")} == {""}
        if definitions == "none":
            con.execute("DROP TABLE message_definitions")
            con.commit()
    finally:
        con.close()
    return path


def write_msg_tree(root: Path) -> Path:
    """A ROS package tree: <root>/mavros_msgs/msg/OverrideRCIn.msg (plus a package.xml, as in a checkout)."""
    pkg = root / "mavros_msgs"
    (pkg / "msg").mkdir(parents=True)
    (pkg / "msg" / "OverrideRCIn.msg").write_text(OVERRIDE_RC_IN)
    (pkg / "package.xml").write_text("<package><name>mavros_msgs</name></package>\n")
    return root


STREAMS: dict[str, Any] = {
    "rc": {"topic": "/mavros/rc/override", "clock": "log",
           "signals": {"pwm1_1": {"field": "channels[0]"}, "pwm2_1": {"field": "channels[1]"},
                       "pwm6_1": {"field": "channels[5]"}}},
    "depth": {"topic": "/bluerov/depth", "clock": "log", "signals": {"depth_m": {"field": "data"}}},
    # what the sensors section refers to, from CSV files (skipped while reading a bag)
    "nav": {"file": "nav.csv", "clock": "column", "csv": {"time_column": "t"},
            "signals": {"u_mps": {"field": "u"}, "v_mps": {"field": "v"}, "w_mps": {"field": "w"},
                        "yaw_rad": {"field": "yaw"}, "n1_rpm": {"field": "n1"}}},
}


def vehicle_doc(message_definitions: list[str] | None = None) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "name": "bluerov",
        "rigid_body": {"mass_kg": 11.5, "inertia_kgm2": [[0.16, 0, 0], [0, 0.16, 0], [0, 0, 0.16]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": "t1", "speed_signal": "n1_rpm", "position_m": [0, 0, 0], "direction": [1, 0, 0],
                       "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
        "sensors": {"dvl": {"velocity": ["u_mps", "v_mps", "w_mps"]}, "attitude": {"yaw": "yaw_rad"}},
        "streams": STREAMS,
    }
    if message_definitions is not None:
        doc["message_definitions"] = message_definitions
    return doc


@pytest.mark.parametrize("definitions", ["empty", "none"])
def test_bag_without_definitions_decodes_with_user_msg_files(tmp_path: Path, definitions: str) -> None:
    import yaml

    bag = write_bag(tmp_path / "dive03", definitions=definitions)
    write_msg_tree(tmp_path / "cfg" / "msgs")
    (tmp_path / "cfg" / "vehicle.yaml").write_text(yaml.safe_dump(vehicle_doc(["msgs"])))
    vehicle = load_vehicle(tmp_path / "cfg" / "vehicle.yaml")  # msgs/ is relative to the vehicle file

    out = ingest_log(bag, vehicle)
    assert not out.quarantine and set(out.tables) == {"rc", "depth"}
    rc = out.tables["rc"]
    np.testing.assert_array_equal(rc["t_ns"].to_numpy(), T0_NS + np.arange(N) * 50_000_000)
    np.testing.assert_array_equal(rc["pwm1_1"].to_numpy(), 1500.0 + 10 * np.arange(N))
    np.testing.assert_array_equal(rc["pwm2_1"].to_numpy(), 1500.0 - 7 * np.arange(N))
    np.testing.assert_array_equal(rc["pwm6_1"].to_numpy(), 1100.0 + np.arange(N))
    depth = out.tables["depth"]
    np.testing.assert_array_equal(depth["t_ns"].to_numpy(), T0_NS + np.arange(N) * 50_000_000 + 7)
    np.testing.assert_array_equal(depth["depth_m"].to_numpy(), 0.5 + 0.01 * np.arange(N))
    assert out.provenance["rc"]["message_type"] == RC
    assert out.report["topics"]["/mavros/rc/override"]["messages_read"] == N


def test_missing_type_names_file_topic_type_and_key(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "dive03", definitions="empty")
    out = ingest_log(bag, Vehicle.model_validate(vehicle_doc()))
    assert [q["stream"] for q in out.quarantine] == ["rc"]  # Float64 is a standard type: only rc is missing
    reason = out.quarantine[0]["reason"]
    for part in ("dive03", "/mavros/rc/override", RC, "`message_definitions`", "mavros_msgs/msg/OverrideRCIn.msg",
                 "is not set"):
        assert part in reason, (part, reason)
    assert out.quarantine[0]["topic"] == "/mavros/rc/override"
    assert "topics" not in out.report  # found before the long read

    # a directory that does not hold the type: named in the error
    other = tmp_path / "other"
    (other / "px4_msgs" / "msg").mkdir(parents=True)
    (other / "px4_msgs" / "msg" / "SensorGps.msg").write_text("uint64 timestamp\nfloat64 latitude_deg\n")
    result = open_log(bag, load_user_types([other])).read({"/mavros/rc/override": ["channels[0]"]})
    assert str(other) in result.failed["/mavros/rc/override"]
    assert RC in result.failed["/mavros/rc/override"]


def test_reader_takes_definitions_and_embedded_ones_win(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "b", definitions="none")
    user = load_user_types([write_msg_tree(tmp_path / "m")])
    assert user.origin[RC] == tmp_path / "m" / "mavros_msgs" / "msg" / "OverrideRCIn.msg"
    with open_log(bag, user) as reader:
        assert reader.undecodable("/mavros/rc/override") is None
        data = reader.read({"/mavros/rc/override": ["channels[17]"]}).topics["/mavros/rc/override"]
    np.testing.assert_array_equal(data.columns["channels[17]"], np.full(N, 65535.0))
    # a user definition of a standard type that contradicts the log's embedded one: the log's wins
    from pipeline.io.fields import TypeRegistry

    wrong = load_user_types([_tree(tmp_path / "w", "std_msgs", "Float64", "float32 data\n")])
    reg = TypeRegistry(ros1=False, user=wrong)
    assert reg.defs[FLOAT64][1][0][1][1][0] == "float32"   # the user's wins over the standard one
    reg.add(FLOAT64, "ros2msg", "float64 data\n")
    assert reg.defs[FLOAT64][1][0][1][1][0] == "float64"   # the embedded one wins over the user's
    reg.add(FLOAT64, "ros2msg", "")                         # an empty embedded definition is no definition
    assert reg.defs[FLOAT64][1][0][1][1][0] == "float64"


def _tree(root: Path, pkg: str, name: str, text: str, *, msg_dir: bool = True) -> Path:
    where = root / pkg / "msg" if msg_dir else root / pkg
    where.mkdir(parents=True, exist_ok=True)
    (where / f"{name}.msg").write_text(text)
    return root


def test_type_names_idl_and_broken_files(tmp_path: Path) -> None:
    assert msgtype_of(Path("/x/mavros_msgs/msg/OverrideRCIn.msg")) == "mavros_msgs/msg/OverrideRCIn"
    assert msgtype_of(Path("/x/custom_msgs/Thrust.msg")) == "custom_msgs/msg/Thrust"
    root = _tree(tmp_path / "d", "custom_msgs", "Thrust", "float32 newtons\nPwm pwm\n", msg_dir=False)
    _tree(root, "custom_msgs", "Pwm", "uint16 us\n")
    _tree(root, "custom_msgs", "Broken", "uint16[ us\n")
    (root / "dvl_msgs" / "msg").mkdir(parents=True)
    (root / "dvl_msgs" / "msg" / "Dvl.idl").write_text(
        "module dvl_msgs { module msg { struct Dvl { double vx; boolean lock; }; }; };\n")
    user = load_user_types([root])
    assert {"custom_msgs/msg/Thrust", "custom_msgs/msg/Pwm", "dvl_msgs/msg/Dvl"} <= set(user.types)
    assert user.types["custom_msgs/msg/Thrust"][1][1] == ("pwm", (2, "custom_msgs/msg/Pwm"))  # same package
    assert "custom_msgs/msg/Broken" not in user.types
    assert "Broken.msg" in user.errors["custom_msgs/msg/Broken"]
    assert "does not parse" in user.missing("custom_msgs/msg/Broken")


def test_missing_directory_names_the_key(tmp_path: Path) -> None:
    import yaml

    (tmp_path / "vehicle.yaml").write_text(yaml.safe_dump(vehicle_doc(["msgs", "nowhere"])))
    (tmp_path / "msgs").mkdir()
    bag = write_bag(tmp_path / "dive03", definitions="empty")
    with pytest.raises(ConfigError, match="'nowhere' does not exist") as info:
        ingest_log(bag, load_vehicle(tmp_path / "vehicle.yaml"))
    assert info.value.field == "message_definitions.1"
