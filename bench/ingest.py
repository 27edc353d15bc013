"""Ingest benchmark (issue 15): ``auvid ingest`` as the user runs it, log -> per-stream Parquet, against rosbags.

    python bench/ingest.py                                          # 10 simulated minutes, all formats, temp dir
    nice python bench/ingest.py --minutes 60 --logs /tmp/trial60 --repeat 3 --json /tmp/b60.json   # issue 15
    python bench/ingest.py --minutes 60 --logs /tmp/trial60 --pin core0 --skip-inproc
    python bench/ingest.py --minutes 240 --logs /tmp/trial240 --repeat 1 --skip-rosbags --formats ros2-mcap
    python bench/ingest.py --minutes 60 --logs /tmp/trial60 --formats mcap-unindexed ros1-unindexed  # streamed
    python bench/ingest.py --minutes 60 --logs /tmp/trial60 --pin core0 --checksum both   # sha256 on and off
    python bench/ingest.py --minutes 60 --logs /tmp/trial60 --pin core0 --configs both    # snapshot / validated

The trial: IMU 120 Hz (sensor_msgs/Imu), gyro 100 Hz (geometry_msgs/Vector3Stamped), pressure 10 Hz
(sensor_msgs/FluidPressure), DVL 4 Hz (a custom type, defined only in the file, with a 10 s drop-out every
minute), thrusters 20 Hz (sensor_msgs/JointState, four named joints). Formats: ROS 2 MCAP uncompressed and
ROS 2 sqlite3 (rosbags writers), MCAP with zstd chunks (mcap writer, wrapped in a bag directory so rosbags can
read it too), ROS 1 bag (rosbags writer).

Every measurement is a fresh child process, and the methods take turns (interleaved), ``--repeat`` rounds, each
round once on any core and once under ``taskset -c 0`` (``--pin``). The tables show the min of N for times and
the max of N for peak RSS. Methods:

* ``auvid``: the whole ``auvid ingest -q --root TMP --vehicle V LOG`` process (console script, imports included,
  into a fresh run directory): what a user or a DVC stage pays; ``--checksum none`` adds ``--no-checksum`` (no
  sha256 of the log for provenance), ``--checksum both`` measures both, interleaved, one table row each. The
  configs come from their snapshot (:mod:`pipeline.config.snapshot`, in a cache directory of the bench's own,
  written by one untimed run first), as in every ingest after the first with the same configs; ``--configs
  validate`` validates them in every run (``AUVID_CACHE_DIR=off``: pydantic imported, the first run's cost),
  ``--configs both`` measures both;
* ``inproc``: the earlier in-process figure: ``pipeline.ingest.ingest_log`` + the stage's ``write_trial`` timed
  inside a child after its imports are warmed (the ADBC driver included);
* ``raw`` / ``deser``: rosbags ``AnyReader`` iterating every message without / with ``deserialize``, each a whole
  child process (rosbags' import and typestore included in its CPU; its own clock starts after the typestore);
* ``cat``: ``cat`` of the log's files to /dev/null, the floor of reading the bytes (warm page cache).

The tree's sources are compiled to bytecode first (``compile_sources``), as an installed copy is. Whole-process
figures come from ``os.wait4``: CPU = user + sys of the child (all its threads; insensitive to the
load on other cores), wall = fork to exit, peak RSS = ``ru_maxrss``. Ratios > 1 mean auvid is faster, except
``auvid ÷ cat`` (how many times reading the bytes auvid takes). The load average is printed at the start, after
each format and at the end. In-process memory: the child's RSS after imports (base), its peak during
``ingest_log`` and its peak including the Parquet writes; Arrow MB = the output tables.
"""

from __future__ import annotations

import argparse
import atexit
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
#: Derived from the generated files: the zstd MCAP without its message indexes and summary, and the ROS 1 bag
#: with its index cut off (a recorder killed before closing). auvid streams them by its record walk; rosbags
#: reads neither, so only auvid and cat are measured on them.
UNINDEXED = {"mcap-unindexed": "mcap-zstd", "ros1-unindexed": "ros1"}
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

    for name in ("pyarrow.parquet", "pipeline.io", "pipeline.io.cdr", "pipeline.io.fields",
                 "pipeline.io.mcap_reader", "pipeline.io.mcap_index", "pipeline.io.rosbag1",
                 "pipeline.io.rosbag1_index", "pipeline.io.rosbag2.reader", "pipeline.io.text"):
        importlib.import_module(name)
    from pipeline.io.fields import _latest

    _latest()  # the standard ROS 2 definitions, parsed once per process


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _reset_peak() -> None:
    """Reset the kernel's peak-RSS mark (VmHWM), so that the ingest's own peak can be read back."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _peak_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def measure(method: str, path: Path, ros1: bool) -> dict[str, Any]:
    extra: dict[str, Any] = {}
    if method == "auvid":
        from pipeline.ingest import ingest_log
        from stages.ingest import write_trial

        vehicle = bench_vehicle()
        _warm_imports()
        base = _rss_mb()
        with tempfile.TemporaryDirectory() as tmp:
            _reset_peak()
            start = time.perf_counter()
            out = ingest_log(path, vehicle)
            read_peak = _peak_mb()
            write_trial(Path(tmp), "trial", out.tables, out.provenance, out.report)
            seconds = time.perf_counter() - start
            peak = _peak_mb()
        count = sum(t["messages_read"] for t in out.report["topics"].values())
        extra = {"paths": {t: r["decode_path"] for t, r in out.report["topics"].items()},
                 "quarantine": out.quarantine, "arrays_mb": sum(t.nbytes for t in out.tables.values()) / 1e6,
                 "base_rss_mb": base, "read_peak_mb": read_peak, "peak_mb": peak}
    else:
        seconds, count = rosbags_reference(path, method, ros1)
        extra = {"peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    return {"method": method, "seconds": seconds, "messages": count, **extra}


def _size_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in _files(path)) / 1e6


def _files(path: Path) -> list[Path]:
    return sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]


def logs_in(outdir: Path, minutes: float, formats: list[str]) -> dict[str, dict[str, Path]]:
    """The generated logs under ``outdir``: reused when its marker file lists them, else generated there."""
    marker = outdir / f"generated-{minutes:g}min.json"
    known: dict[str, dict[str, Path]] = {}
    if marker.exists():
        known = {f: {k: Path(v) for k, v in p.items()} for f, p in json.loads(marker.read_text()).items()}
        if all(f in known for f in formats):
            return {f: known[f] for f in formats}
    outdir.mkdir(parents=True, exist_ok=True)
    for sub in ("ros2_mcap", "mcap_zstd", "ros2_sqlite3", "trial.bag"):
        if (outdir / sub).exists():
            raise SystemExit(f"{outdir / sub} exists but {marker.name} does not list every format asked for: "
                             "use an empty --logs directory")
    start = time.perf_counter()
    logs = generate(outdir, minutes, [f for f in FORMATS if f in formats])
    print(f"generated {minutes:g} min in {time.perf_counter() - start:.0f} s under {outdir}", flush=True)
    marker.write_text(json.dumps({f: {k: str(v) for k, v in p.items()} for f, p in logs.items()}))
    return {f: logs[f] for f in formats}


def unindexed_logs(outdir: Path, logs: dict[str, dict[str, Path]], formats: list[str]) -> dict[str, dict[str, Path]]:
    """The unindexed copies asked for (:data:`UNINDEXED`), written under ``outdir/unindexed`` once."""
    out = {}
    for fmt in formats:
        if fmt not in UNINDEXED:
            continue
        src = logs[UNINDEXED[fmt]]["auvid"]
        dst = outdir / "unindexed" / ("mcap_unindexed.mcap" if fmt == "mcap-unindexed" else "trial_unindexed.bag")
        if not dst.exists():
            dst.parent.mkdir(exist_ok=True)
            tmp = dst.with_suffix(".partial")
            (strip_mcap_index if fmt == "mcap-unindexed" else strip_bag_index)(src, tmp)
            tmp.replace(dst)
        out[fmt] = {"auvid": dst}
    return out


def strip_mcap_index(src: Path, dst: Path) -> None:
    """``src`` without message indexes, summary and summary offsets: the data section's records up to DataEnd (its
    CRC zeroed), then a footer that points at no summary."""
    import struct

    data = src.read_bytes()
    magic = data[:8]
    out, pos = [magic], 8
    while True:
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x0F:  # DataEnd: the data section ends here
            break
        if op != 0x07:  # message indexes go
            out.append(data[pos:pos + 9 + length])
        pos += 9 + length
    out.append(struct.pack("<BQI", 0x0F, 4, 0))
    out.append(struct.pack("<BQQQI", 0x02, 20, 0, 0, 0))
    out.append(magic)
    dst.write_bytes(b"".join(out))


def strip_bag_index(src: Path, dst: Path) -> None:
    """``src`` cut at its index section, with index_pos 0 in the bag header (as a recorder killed mid-trial
    leaves it)."""
    data = bytearray(src.read_bytes())
    at = data.index(b"index_pos=") + len(b"index_pos=")
    index_pos = int.from_bytes(data[at:at + 8], "little")
    data[at:at + 8] = bytes(8)
    dst.write_bytes(bytes(data[:index_pos]))


def compile_sources(root: Path) -> None:
    """Compile the tree's ``pipeline`` and ``stages`` to bytecode (``__pycache__``, ignored by git), as ``pip
    install`` does: with ``PYTHONDONTWRITEBYTECODE`` set (as in some CI and sandbox environments) every child
    would otherwise compile the sources again, ~0.04 s of CPU that no installed copy pays."""
    import compileall

    for sub in ("pipeline", "stages"):
        if (root / sub).is_dir():
            compileall.compile_dir(root / sub, quiet=1)


def _loadavg() -> str:
    with open("/proc/loadavg") as fh:
        return " ".join(fh.read().split()[:3])


# -- whole processes --------------------------------------------------------------------------------------------
PIN = ["taskset", "-c", "0"]  # one core: the sha256 thread and the Parquet writer threads get no second one
CHILD_ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


#: A lean process that starts every measured child. On Linux a child's ``ru_maxrss`` is at least its parent's peak
#: RSS (the parent's memory counts until the child's exec), so children started from this script, which has numpy,
#: pydantic and the bench's data in it, would all report its peak. This spawner holds ~10 MiB.
SPAWNER = r"""
import json, os, subprocess, sys, time
for line in sys.stdin:
    req = json.loads(line)
    with open(req["out"], "w") as out, open(req["err"], "w") as err:
        start = time.perf_counter()
        proc = subprocess.Popen(req["cmd"], stdin=subprocess.DEVNULL, stdout=out if req["capture"] else
                                subprocess.DEVNULL, stderr=err, cwd=req["cwd"], env=req["env"])
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    print(json.dumps({"rc": proc.returncode, "wall_s": wall, "user_s": usage.ru_utime, "sys_s": usage.ru_stime,
                      "rss_mib": usage.ru_maxrss / 1024.0, "minflt": usage.ru_minflt}), flush=True)
"""
_spawner: list[subprocess.Popen[str]] = []


def run_process(cmd: list[str], pin: bool, capture: bool = True, env: dict[str, str] | None = None) -> dict[str, Any]:
    """Run ``cmd`` as a child (under ``taskset -c 0`` when ``pin``) and return its own resource use.

    The lean spawner (:data:`SPAWNER`) starts it and reads ``os.wait4``'s rusage: CPU = user + sys of every thread
    of the process (imports included), insensitive to how busy the other cores are; wall = from fork to exit, as
    the user waits; peak RSS = ``ru_maxrss``; ``minflt``: its minor page faults (fresh pages it touched, each
    zeroed by the kernel). ``taskset`` execs the command, so the rusage is the command's.
    """
    if not _spawner:
        _spawner.append(subprocess.Popen([sys.executable, "-I", "-S", "-c", SPAWNER], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True))
    spawner = _spawner[0]
    full = [*PIN, *cmd] if pin else cmd
    with tempfile.NamedTemporaryFile("r") as out, tempfile.NamedTemporaryFile("r") as err:
        assert spawner.stdin is not None and spawner.stdout is not None
        spawner.stdin.write(json.dumps({"cmd": full, "out": out.name, "err": err.name, "capture": capture,
                                        "cwd": str(ROOT), "env": {**CHILD_ENV, **(env or {})}}) + "\n")
        spawner.stdin.flush()
        got = json.loads(spawner.stdout.readline())
        stdout, stderr = out.read(), err.read()
    if got.pop("rc") != 0:
        raise RuntimeError(f"{' '.join(full)} failed:\n{stderr[-3000:]}")
    return {"cpu_s": got["user_s"] + got["sys_s"], **got, "stdout": stdout}


def auvid_command() -> list[str]:
    """``auvid`` as the user runs it: the console script beside this interpreter (else ``python -m``)."""
    script = Path(sys.executable).with_name("auvid")
    return [str(script)] if script.exists() else [sys.executable, "-m", "pipeline.cli"]


def vehicle_yaml(outdir: Path) -> Path:
    """The bench vehicle as the YAML file ``auvid ingest --vehicle`` reads."""
    import yaml

    doc = bench_vehicle().model_dump(mode="json", exclude_none=True, by_alias=True)
    path = outdir / "bench-vehicle.yaml"
    text = yaml.safe_dump(doc, sort_keys=False)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


def process_auvid(log: Path, vehicle: Path, pin: bool, checksum: str = "sha256",
                  configs: str = "snapshot") -> dict[str, Any]:
    """A whole ``auvid ingest -q`` process into a fresh run directory (removed after, outside the measurement);
    ``checksum`` ``none``: with ``--no-checksum``; ``configs`` ``validate``: with ``AUVID_CACHE_DIR=off``."""
    flags = ["--no-checksum"] if checksum == "none" else []
    env = {"AUVID_CACHE_DIR": "off"} if configs == "validate" else None
    with tempfile.TemporaryDirectory(prefix="auvid-bench-run-") as tmp:
        got = run_process([*auvid_command(), "ingest", "-q", "--root", tmp, "--vehicle", str(vehicle), *flags,
                           str(log)], pin, env=env)
        reports = sorted(Path(tmp).glob("data/signals/*/ingest_report.json"))
        if len(reports) != 1:
            raise RuntimeError(f"auvid ingest of {log} wrote {len(reports)} reports: {got['stdout'][-2000:]}")
        report = json.loads(reports[0].read_text())
        if report.get("checksum", "sha256") != checksum:
            raise RuntimeError(f"auvid ingest of {log} ran with checksum {report.get('checksum')}, not {checksum}")
    got["messages"] = sum(t["messages_read"] for t in report["topics"].values())
    got["paths"] = sorted({t["decode_path"] for t in report["topics"].values()})
    return got


def process_measure(method: str, path: Path, ros1: bool, pin: bool) -> dict[str, Any]:
    """A child running ``--measure`` (in-process auvid, or a rosbags reference): its own clock and the process's."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--measure", method, "--path", str(path)]
    got = run_process(cmd + (["--ros1"] if ros1 else []), pin)
    return {**json.loads(got.pop("stdout").strip().splitlines()[-1]), **got}


def process_cat(path: Path, pin: bool) -> dict[str, Any]:
    """``cat`` of the log's files to /dev/null: reading the bytes, the floor of any reader."""
    got = run_process(["cat", *map(str, _files(path))], pin, capture=False)
    got["messages"] = None
    return got


METHODS = ("auvid", "inproc", "raw", "deser", "cat")
#: The whole-process auvid method of each checksum mode (``--checksum``; "-none": ``--no-checksum``) and way to the
#: configs (``--configs``; "-validate": validated in the run, no snapshot).
AUVID_METHODS = {("sha256", "snapshot"): "auvid", ("none", "snapshot"): "auvid-none",
                 ("sha256", "validate"): "auvid-validate", ("none", "validate"): "auvid-none-validate"}


def _best(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Min of N for times (the least disturbed run), max of N for peak RSS."""
    if not runs:
        return {}
    out = dict(runs[0])
    for key in ("cpu_s", "user_s", "sys_s", "wall_s", "seconds"):
        if key in out:
            out[key] = min(r[key] for r in runs)
    for key in ("rss_mib", "peak_mb", "read_peak_mb"):
        if key in out:
            out[key] = max(r[key] for r in runs)
    return out


PROCESS_HEAD = ("| format | MB | messages | cores | auvid CPU s | auvid wall s | deser ÷ auvid, CPU | raw ÷ auvid, CPU "
                "| deser ÷ auvid, wall | raw ÷ auvid, wall | auvid ÷ cat, wall | raw / deser CPU s | cat wall s "
                "| peak RSS MiB: auvid / raw / deser | Arrow MB |")
INPROC_HEAD = ("| format | cores | auvid in-process s | raw / deser in-process s | × raw | × deser "
               "| auvid peak RSS − base MB: ingest / +Parquet (base) | paths |")


def _ratio(num: dict[str, Any], den: dict[str, Any], key: str) -> str:
    return f"{num[key] / den[key]:.1f}×" if num and den and den.get(key) else "–"


def _val(m: dict[str, Any], key: str, spec: str = ".2f") -> str:
    return format(m[key], spec) if m and m.get(key) is not None else "–"


def process_row(fmt: str, size: float, pin: bool, b: dict[str, dict[str, Any]]) -> str:
    a, r, d, c, i = (b.get(m, {}) for m in ("auvid", "raw", "deser", "cat", "inproc"))
    cells = [fmt, f"{size:.1f}", _val(a, "messages", ","), "taskset -c 0" if pin else "any",
             _val(a, "cpu_s"), _val(a, "wall_s"), _ratio(d, a, "cpu_s"), _ratio(r, a, "cpu_s"),
             _ratio(d, a, "wall_s"), _ratio(r, a, "wall_s"), _ratio(a, c, "wall_s"),
             f"{_val(r, 'cpu_s')} / {_val(d, 'cpu_s')}", _val(c, "wall_s"),
             " / ".join(_val(m, "rss_mib", ".0f") for m in (a, r, d)), _val(i, "arrays_mb", ".1f")]
    return "| " + " | ".join(cells) + " |"


def inproc_row(fmt: str, pin: bool, b: dict[str, dict[str, Any]]) -> str:
    i, r, d = b.get("inproc", {}), b.get("raw", {}), b.get("deser", {})
    if not i:
        return ""
    base = i["base_rss_mb"]
    refs = f"{r['seconds']:.2f} / {d['seconds']:.2f}" if r and d else "–"
    return (f"| {fmt} | {'taskset -c 0' if pin else 'any'} | {i['seconds']:.3f} | {refs} | "
            f"{_ratio(r, i, 'seconds')} | {_ratio(d, i, 'seconds')} | "
            f"{i['read_peak_mb'] - base:.0f} / {i['peak_mb'] - base:.0f} ({base:.0f}) | "
            f"{','.join(sorted(set(i['paths'].values())))}"
            + (f" QUARANTINE {i['quarantine']}" if i["quarantine"] else "") + " |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--formats", nargs="+", choices=[*FORMATS, *UNINDEXED], default=list(FORMATS))
    parser.add_argument("--logs", type=Path, default=None, help="generate into / reuse the logs of this directory")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each measurement (the tables show the min)")
    parser.add_argument("--pin", choices=("both", "any", "core0"), default="both",
                        help="run each child on any core, pinned to core 0 (taskset -c 0), or both (default)")
    parser.add_argument("--skip-rosbags", action="store_true", help="no rosbags references")
    parser.add_argument("--skip-inproc", action="store_true", help="no in-process auvid figure")
    parser.add_argument("--checksum", choices=("sha256", "none", "both"), default="sha256",
                        help="auvid ingest with the log's sha256 (default), with --no-checksum, or both (interleaved, "
                             "one row each); the in-process figure keeps the default")
    parser.add_argument("--configs", choices=("snapshot", "validate", "both"), default="snapshot",
                        help="auvid ingest reading the configs from their snapshot (default: as every run after the "
                             "first), validating them (AUVID_CACHE_DIR=off: the first run's cost), or both")
    parser.add_argument("--json", type=Path, default=None, help="also write every run as JSON here")
    parser.add_argument("--measure", choices=("auvid", "raw", "deser"), help=argparse.SUPPRESS)
    parser.add_argument("--path", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--ros1", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:
        print(json.dumps(measure(args.measure, args.path, args.ros1)))
        return 0
    outdir = args.logs or Path(tempfile.mkdtemp(prefix="auvid-bench-"))
    compile_sources(ROOT)
    base = list(dict.fromkeys(UNINDEXED.get(f, f) for f in args.formats))
    logs = logs_in(outdir, args.minutes, base)
    logs = {**logs, **unindexed_logs(outdir, logs, args.formats)}
    logs = {f: logs[f] for f in args.formats}
    vehicle = vehicle_yaml(outdir)
    pins = {"both": [False, True], "any": [False], "core0": [True]}[args.pin]
    checksums = ["sha256", "none"] if args.checksum == "both" else [args.checksum]
    ways = ["snapshot", "validate"] if args.configs == "both" else [args.configs]
    variants = [(c, w) for c in checksums for w in ways]
    auvid_methods = [AUVID_METHODS[v] for v in variants]
    by_method = {AUVID_METHODS[v]: v for v in variants}
    CHILD_ENV["AUVID_CACHE_DIR"] = tempfile.mkdtemp(prefix="auvid-bench-cache-")  # the bench's own snapshots
    atexit.register(shutil.rmtree, CHILD_ENV["AUVID_CACHE_DIR"], True)
    if "snapshot" in ways:  # written once, untimed: every timed run with the snapshot reads it
        process_auvid(next(iter(logs.values()))["auvid"], vehicle, pin=False, checksum="none")
    methods = [*auvid_methods, *(m for m in METHODS[1:] if not (args.skip_rosbags and m in ("raw", "deser"))
                                 and not (args.skip_inproc and m == "inproc"))]
    print(f"{time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} CPUs, load average {_loadavg()}; "
          f"{args.minutes:g} min, min of {args.repeat}, {' '.join(auvid_command())}", flush=True)
    rows, process_lines, inproc_lines = [], [], []
    for fmt, paths in logs.items():
        ros1 = fmt.startswith("ros1")
        todo = [m for m in methods if "rosbags" in paths or m not in ("raw", "deser")]
        runs: dict[str, list[dict[str, Any]]] = {f"{m}/{int(p)}": [] for m in todo for p in pins}
        for _ in range(args.repeat):  # interleaved: every method and pinning once per round
            for pin in pins:
                for method in todo:
                    if method in auvid_methods:
                        got = process_auvid(paths["auvid"], vehicle, pin, *by_method[method])
                    elif method == "cat":
                        got = process_cat(paths["auvid"], pin)
                    else:
                        key = "auvid" if method == "inproc" else method
                        got = process_measure(key, paths["auvid" if method == "inproc" else "rosbags"], ros1, pin)
                    runs[f"{method}/{int(pin)}"].append(got)
        size = _size_mb(paths["auvid"])
        load = _loadavg()
        for pin in pins:
            measured = {m: _best(runs[f"{m}/{int(pin)}"]) for m in todo}
            others = {m: b for m, b in measured.items() if m not in auvid_methods}
            for checksum, way in variants:
                best = {**others, "auvid": measured[AUVID_METHODS[checksum, way]]}
                said = ([f"checksum {checksum}"] if len(checksums) > 1 or checksum != "sha256" else []) + (
                    [f"configs {'from snapshot' if way == 'snapshot' else 'validated'}"]
                    if len(ways) > 1 or way != "snapshot" else [])
                label = ", ".join([fmt, *said])
                process_lines.append(process_row(label, size, pin, best))
                print(process_lines[-1], flush=True)
                if "raw" in best and best["raw"]["messages"] != best["auvid"]["messages"]:
                    print(f"  note: rosbags read {best['raw']['messages']} messages, auvid "
                          f"{best['auvid']['messages']}")
                rows.append({"format": fmt, "size_mb": size, "minutes": args.minutes, "pinned": pin, "load": load,
                             "checksum": checksum, "configs": way, **best})
            inproc_lines.append(inproc_row(fmt, pin, others))
        rows[-1]["runs"] = runs
        print(f"  ({fmt} done, load average {load})", flush=True)
    print(f"\nWhole process, min of {args.repeat} (load average at the end {_loadavg()}):\n")
    print(PROCESS_HEAD)
    print("|" + "---|" * (PROCESS_HEAD.count("|") - 1))
    print("\n".join(process_lines))
    if "inproc" in methods:
        print("\nIn-process (the clock starts after the imports; rosbags: after building its typestore):\n")
        print(INPROC_HEAD)
        print("|" + "---|" * (INPROC_HEAD.count("|") - 1))
        print("\n".join(line for line in inproc_lines if line))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
