"""Ingest benchmark: generate one trial in each log format, then time auvid's ingest against rosbags.

    python bench/ingest.py                       # 10 simulated minutes (~150k messages), all formats
    python bench/ingest.py --minutes 60          # the one-hour trial of DESIGN.md (~910k messages)
    python bench/ingest.py --formats mcap-zstd ros1 --keep /tmp/bench

The trial: IMU 120 Hz (sensor_msgs/Imu), gyro 100 Hz (geometry_msgs/Vector3Stamped), pressure 10 Hz
(sensor_msgs/FluidPressure), DVL 4 Hz (a custom type, defined only in the file, with a 10 s drop-out every
minute), thrusters 20 Hz (sensor_msgs/JointState, four named joints). Formats: ROS 2 MCAP uncompressed and
ROS 2 sqlite3 (rosbags writers), MCAP with zstd chunks (mcap writer, wrapped in a bag directory so rosbags can
read it too), ROS 1 bag (rosbags writer).

Each measurement runs in its own subprocess (peak RSS is the child's ``ru_maxrss``, imports included):
``auvid`` = ``ingest_log`` + writing every stream's Parquet; ``raw`` = rosbags ``AnyReader`` iterating every
message without deserializing; ``deser`` = the same plus ``deserialize``. Ratios > 1 mean auvid is faster.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

FORMATS = ("ros2-mcap", "mcap-zstd", "ros2-sqlite3", "ros1")
DVL_MSG = """std_msgs/Header header
geometry_msgs/Vector3 velocity
float32 altitude
bool bottom_lock
"""
DVL_TYPE = "auvid_bench/msg/Dvl"
JOINTS = ["th1", "th2", "th3", "th4"]
T0_NS = 1_700_000_000_000_000_000
TOPICS = {  # topic: (type, rate_hz)
    "/imu/data": ("sensor_msgs/msg/Imu", 120.0),
    "/gyro/rate": ("geometry_msgs/msg/Vector3Stamped", 100.0),
    "/pressure": ("sensor_msgs/msg/FluidPressure", 10.0),
    "/dvl/data": (DVL_TYPE, 4.0),
    "/thrusters/joint_states": ("sensor_msgs/msg/JointState", 20.0),
}


# -- generation -------------------------------------------------------------------------------------------------
def typestore(ros1: bool) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(DVL_MSG, DVL_TYPE))
    return store



def rosbags_reference(path: Path, method: str, ros1: bool) -> tuple[float, int]:
    """rosbags AnyReader over every message: ``raw`` iteration, or ``deser`` with deserialization.

    Returns (seconds, messages). The typestore is built before the clock starts.
    """
    from rosbags.highlevel import AnyReader

    store = typestore(ros1)
    count = 0
    start = time.perf_counter()
    with AnyReader([path], default_typestore=store) as reader:
        deser = method == "deser"
        for conn, _t, raw in reader.messages(connections=reader.connections):
            if deser:
                reader.deserialize(raw, conn.msgtype)
            count += 1
    return time.perf_counter() - start, count

def schedule(minutes: float) -> dict[str, np.ndarray]:
    """Log time stamps per topic; the DVL loses lock (no message) for 10 s of every minute."""
    span_ns = int(minutes * 60e9)
    out = {}
    for topic, (_, rate) in TOPICS.items():
        step = int(round(1e9 / rate))
        t = np.arange(T0_NS, T0_NS + span_ns, step, dtype=np.int64)
        if topic == "/dvl/data":
            t = t[((t - T0_NS) % 60_000_000_000) >= 10_000_000_000]
        out[topic] = t
    return out


def payloads(store: Any, ros1: bool, stamps: dict[str, np.ndarray]) -> dict[str, list[bytes]]:
    """Serialized messages per topic (values vary smoothly; the header stamp lags log time by 2 ms)."""
    T = store.types
    ser = store.serialize_ros1 if ros1 else store.serialize_cdr
    Time, Vec = T["builtin_interfaces/msg/Time"], T["geometry_msgs/msg/Vector3"]
    Quat = T["geometry_msgs/msg/Quaternion"]

    def header(i: int, t: int, frame: str) -> Any:
        stamp = Time(sec=(t - 2_000_000) // 1_000_000_000, nanosec=(t - 2_000_000) % 1_000_000_000)
        if ros1:
            return T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id=frame)
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    cov = np.zeros(9, dtype=np.float64)
    out: dict[str, list[bytes]] = {}
    for topic, (msgtype, _) in TOPICS.items():
        ts = stamps[topic]
        x = (ts - T0_NS) / 1e9
        msgs: list[bytes] = []
        if msgtype.endswith("Imu"):
            yaw = 0.3 * np.sin(x / 20.0)
            for i, t in enumerate(ts.tolist()):
                m = T[msgtype](header=header(i, t, "imu"),
                               orientation=Quat(x=0.0, y=0.0, z=math.sin(yaw[i] / 2), w=math.cos(yaw[i] / 2)),
                               orientation_covariance=cov, angular_velocity=Vec(x=0.01, y=-0.02, z=float(yaw[i])),
                               angular_velocity_covariance=cov,
                               linear_acceleration=Vec(x=float(np.cos(x[i])), y=0.0, z=9.81),
                               linear_acceleration_covariance=cov)
                msgs.append(bytes(ser(m, msgtype)))
        elif msgtype.endswith("Vector3Stamped"):
            for i, t in enumerate(ts.tolist()):
                m = T[msgtype](header=header(i, t, "fog"), vector=Vec(x=0.0, y=0.0, z=float(np.sin(x[i]))))
                msgs.append(bytes(ser(m, msgtype)))
        elif msgtype.endswith("FluidPressure"):
            for i, t in enumerate(ts.tolist()):
                m = T[msgtype](header=header(i, t, "ps"), fluid_pressure=101325.0 + 1e4 * float(np.sin(x[i] / 60)),
                               variance=0.0)
                msgs.append(bytes(ser(m, msgtype)))
        elif msgtype == DVL_TYPE:
            for i, t in enumerate(ts.tolist()):
                m = T[msgtype](header=header(i, t, "dvl"),
                               velocity=Vec(x=float(np.cos(x[i] / 10)), y=0.05, z=0.0),
                               altitude=np.float32(3.0), bottom_lock=True)
                msgs.append(bytes(ser(m, msgtype)))
        else:
            zeros = np.zeros(4, dtype=np.float64)
            for i, t in enumerate(ts.tolist()):
                vel = np.array([100.0, -100.0, 50.0, -50.0]) * float(np.sin(x[i] / 5))
                m = T[msgtype](header=header(i, t, "thr"), name=JOINTS, position=zeros, velocity=vel, effort=zeros)
                msgs.append(bytes(ser(m, msgtype)))
        out[topic] = msgs
    return out


def _order(stamps: dict[str, np.ndarray]) -> list[tuple[str, int, int]]:
    rows = [(int(t), k, i) for k, topic in enumerate(TOPICS) for i, t in enumerate(stamps[topic].tolist())]
    rows.sort()
    names = list(TOPICS)
    return [(names[k], i, t) for t, k, i in rows]


def write_rosbag2(path: Path, storage: str, store: Any, data: dict[str, list[bytes]],
                  order: list[tuple[str, int, int]]) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {topic: writer.add_connection(topic, msgtype, typestore=store)
                 for topic, (msgtype, _) in TOPICS.items()}
        for topic, i, t in order:
            writer.write(conns[topic], t, data[topic][i])


def write_mcap_zstd(path: Path, store: Any, data: dict[str, list[bytes]], order: list[tuple[str, int, int]],
                    metadata_from: Path) -> None:
    """A bag directory holding one zstd-chunked MCAP (mcap writer) and a copy of the uncompressed bag's metadata."""
    from mcap.writer import CompressionType, Writer

    path.mkdir(parents=True)
    name = f"{path.name}_0.mcap"
    with open(path / name, "wb") as fh:
        writer = Writer(fh, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        writer.start(profile="ros2", library="auvid-bench")
        channels = {}
        for topic, (msgtype, _) in TOPICS.items():
            msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
            sid = writer.register_schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())
            channels[topic] = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)
        for topic, i, t in order:
            writer.add_message(channels[topic], log_time=t, data=data[topic][i], publish_time=t)
        writer.finish()
    src = next(metadata_from.glob("*.mcap")).name
    (path / "metadata.yaml").write_text((metadata_from / "metadata.yaml").read_text().replace(src, name))


def write_ros1(path: Path, store: Any, data: dict[str, list[bytes]], order: list[tuple[str, int, int]]) -> None:
    from rosbags.rosbag1 import Writer

    with Writer(path) as writer:
        conns = {topic: writer.add_connection(topic, msgtype, typestore=store)
                 for topic, (msgtype, _) in TOPICS.items()}
        for topic, i, t in order:
            writer.write(conns[topic], t, data[topic][i])


def generate(outdir: Path, minutes: float, formats: list[str]) -> dict[str, dict[str, Path]]:
    """Write the trial in each format; returns format -> {"auvid": path to ingest, "rosbags": path for AnyReader}."""
    stamps = schedule(minutes)
    order = _order(stamps)
    logs: dict[str, dict[str, Path]] = {}
    need2 = [f for f in formats if f != "ros1"]
    if need2:
        store2 = typestore(False)
        data2 = payloads(store2, False, stamps)
        mcap_dir = outdir / "ros2_mcap"
        if "ros2-mcap" in formats or "mcap-zstd" in formats:
            write_rosbag2(mcap_dir, "mcap", store2, data2, order)
            logs["ros2-mcap"] = {"auvid": mcap_dir, "rosbags": mcap_dir}
        if "mcap-zstd" in formats:
            zdir = outdir / "mcap_zstd"
            write_mcap_zstd(zdir, store2, data2, order, mcap_dir)
            logs["mcap-zstd"] = {"auvid": zdir / "mcap_zstd_0.mcap", "rosbags": zdir}
        if "ros2-sqlite3" in formats:
            write_rosbag2(outdir / "ros2_sqlite3", "sqlite3", store2, data2, order)
            logs["ros2-sqlite3"] = {"auvid": outdir / "ros2_sqlite3", "rosbags": outdir / "ros2_sqlite3"}
        del data2
    if "ros1" in formats:
        store1 = typestore(True)
        data1 = payloads(store1, True, stamps)
        write_ros1(outdir / "trial.bag", store1, data1, order)
        logs["ros1"] = {"auvid": outdir / "trial.bag", "rosbags": outdir / "trial.bag"}
    return {f: logs[f] for f in formats if f in logs}


def bench_vehicle() -> Any:
    from pipeline.config import Vehicle

    thr = {f"n{k + 1}_rpm": {"field": f"velocity[name={j}]", "unit": "rad/s"} for k, j in enumerate(JOINTS)}
    return Vehicle.model_validate({
        "name": "benchbot",
        "rigid_body": {"mass_kg": 30, "inertia_kgm2": [[1, 0, 0], [0, 2, 0], [0, 0, 2]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": j, "speed_signal": f"n{k + 1}_rpm", "position_m": [0, 0, 0], "direction": [1, 0, 0],
                       "thrust": {"k_fwd_N_per_rpm2": 1e-5}} for k, j in enumerate(JOINTS)],
        "sensors": {"dvl": {"velocity": ["u_dvl_mps", "v_dvl_mps", "w_dvl_mps"], "valid": "dvl_lock_flag"},
                    "attitude": {"quaternion": "att_quat", "convention": "flu_enu"}},
        "streams": {
            "imu": {"topic": "/imu/data", "clock": "header",
                    "signals": {"att_quat": {"field": "orientation"}, "r_imu_radps": {"field": "angular_velocity.z"},
                                "ax_mps2": {"field": "linear_acceleration.x"}}},
            "gyro": {"topic": "/gyro/rate", "clock": "header", "signals": {"r_fog_radps": {"field": "vector.z"}}},
            "pressure": {"topic": "/pressure", "clock": "log", "signals": {"p_Pa": {"field": "fluid_pressure"}}},
            "dvl": {"topic": "/dvl/data", "clock": "header",
                    "signals": {"u_dvl_mps": {"field": "velocity.x"}, "v_dvl_mps": {"field": "velocity.y"},
                                "w_dvl_mps": {"field": "velocity.z"}, "dvl_lock_flag": {"field": "bottom_lock"}}},
            "thrusters": {"topic": "/thrusters/joint_states", "clock": "header", "signals": thr},
        },
    })


# -- measurement (one per subprocess) ---------------------------------------------------------------------------
def _warm_imports() -> None:
    """Import what ingest imports lazily, so that a measurement is the steady per-log cost of a batch."""
    import importlib

    for name in ("pandas", "pyarrow.parquet", "pipeline.io", "pipeline.io.cdr", "pipeline.io.fields",
                 "pipeline.io.mcap_reader", "pipeline.io.rosbag1", "pipeline.io.rosbag2", "pipeline.io.text"):
        importlib.import_module(name)


def measure(method: str, path: Path, ros1: bool) -> dict[str, Any]:
    if method == "auvid":
        from pipeline.ingest import ingest_log
        from pipeline.tableio import write_parquet

        vehicle = bench_vehicle()
        _warm_imports()
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            out = ingest_log(path, vehicle)
            for stream, table in out.tables.items():
                write_parquet(table, Path(tmp) / f"{stream}.parquet", out.provenance[stream])
            seconds = time.perf_counter() - start
        count = sum(t["messages_read"] for t in out.report["topics"].values())
        paths = sorted({t["decode_path"] for t in out.report["topics"].values()})
        extra = {"decode_paths": paths, "quarantine": out.quarantine}
    else:
        seconds, count = rosbags_reference(path, method, ros1)
        extra = {}
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {"method": method, "seconds": seconds, "messages": count, "peak_rss_mb": rss_mb, **extra}


def _size_mb(path: Path) -> float:
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else [path]
    return sum(p.stat().st_size for p in files) / 1e6


def _child(method: str, path: Path, ros1: bool) -> dict[str, Any]:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--measure", method, "--path", str(path)]
    if ros1:
        cmd.append("--ros1")
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    if proc.returncode != 0:
        return {"method": method, "error": proc.stderr.strip().splitlines()[-1] if proc.stderr else "failed"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS))
    parser.add_argument("--keep", type=Path, default=None, help="write the logs here and keep them")
    parser.add_argument("--measure", choices=("auvid", "raw", "deser"), help=argparse.SUPPRESS)
    parser.add_argument("--path", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--ros1", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--json", type=Path, default=None, help="also write the results as JSON here")
    args = parser.parse_args(argv)
    if args.measure:
        print(json.dumps(measure(args.measure, args.path, args.ros1)))
        return 0

    outdir = args.keep or Path(tempfile.mkdtemp(prefix="auvid-bench-"))
    outdir.mkdir(parents=True, exist_ok=True)
    try:
        start = time.perf_counter()
        logs = generate(outdir, args.minutes, args.formats)
        print(f"generated {args.minutes:g} min in {time.perf_counter() - start:.1f} s under {outdir}", flush=True)
        rows = []
        for fmt, paths in logs.items():
            ros1 = fmt == "ros1"
            res = {m: _child(m, paths["auvid" if m == "auvid" else "rosbags"], ros1) for m in ("auvid", "raw", "deser")}
            rows.append({"format": fmt, "size_mb": _size_mb(paths["auvid"]), **res})
            _print_row(rows[-1])
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2))
    finally:
        if args.keep is None:
            shutil.rmtree(outdir, ignore_errors=True)
    return 0


_HEADER_PRINTED = False


def _print_row(row: dict[str, Any]) -> None:
    global _HEADER_PRINTED
    if not _HEADER_PRINTED:
        print(f"{'format':<13} {'MB':>7} {'messages':>9} {'auvid s':>8} {'MB/s':>7} {'msgs/s':>9} "
              f"{'raw s':>7} {'deser s':>8} {'x raw':>6} {'x deser':>7} {'RSS MB auvid/raw/deser':>23}  paths")
        _HEADER_PRINTED = True
    a, r, d = row["auvid"], row["raw"], row["deser"]
    for m in (a, r, d):
        if "error" in m:
            print(f"{row['format']:<13} {m['method']} failed: {m['error']}")
    if any("error" in m for m in (a, r, d)):
        return
    print(f"{row['format']:<13} {row['size_mb']:7.1f} {a['messages']:9d} {a['seconds']:8.2f} "
          f"{row['size_mb'] / a['seconds']:7.1f} {a['messages'] / a['seconds']:9.0f} {r['seconds']:7.2f} "
          f"{d['seconds']:8.2f} {r['seconds'] / a['seconds']:6.1f} {d['seconds'] / a['seconds']:7.1f} "
          f"{a['peak_rss_mb']:7.0f}/{r['peak_rss_mb']:.0f}/{d['peak_rss_mb']:.0f}  {','.join(a['decode_paths'])}"
          + (f"  QUARANTINE {a['quarantine']}" if a["quarantine"] else ""))
    if r["messages"] != a["messages"]:
        print(f"  note: rosbags read {r['messages']} messages, auvid {a['messages']}")


if __name__ == "__main__":
    raise SystemExit(main())
