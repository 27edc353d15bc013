"""Fast-ingest benchmark: auvid's readers (``read()`` + one Parquet file per stream) against rosbags, same files.

    python bench/ingest_fast.py --minutes 10                      # generate (bench/ingest.py) and measure
    python bench/ingest_fast.py --minutes 60 --logs /tmp/trial60  # keep / reuse the generated logs there
    python bench/ingest_fast.py --minutes 60 --logs /tmp/trial60 --repeat 3 --markdown docs/benchmarks.md

The trial and its four formats come from ``bench/ingest.py`` (IMU 120 Hz, gyro 100 Hz, pressure 10 Hz, DVL 4 Hz
with drop-outs, JointState thrusters 20 Hz). Every measurement runs in a fresh subprocess; times are medians of
``--repeat`` runs. ``auvid`` = open the log, list topics, ``read()`` the configured fields, write one Parquet file
per topic; ``raw`` = rosbags ``AnyReader`` iterating every message without deserializing; ``deser`` = the same
plus ``deserialize``. Memory: the child's peak RSS, its RSS after imports, and the size of the extracted arrays
(columns, log and header stamps); the target is peak - baseline <= 2 x arrays + a constant.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "bench"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

FORMATS = ("ros2-mcap", "mcap-zstd", "ros2-sqlite3", "ros1")
REQUESTS = {
    "/imu/data": ["orientation.x", "orientation.y", "orientation.z", "orientation.w", "angular_velocity.z",
                  "linear_acceleration.x"],
    "/gyro/rate": ["vector.z"],
    "/pressure": ["fluid_pressure"],
    "/dvl/data": ["velocity.x", "velocity.y", "velocity.z", "bottom_lock"],
    "/thrusters/joint_states": [f"velocity[name=th{k}]" for k in range(1, 5)],
}


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _reset_peak() -> None:
    """Reset the kernel's peak-RSS mark (VmHWM) so that the read's own peak can be read back."""
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
        # Warm what a batch of ingests pays once (rosbags' typestore is built before its clock starts too).
        import pandas  # noqa: F401 - pyarrow imports it lazily on the first table
        import pyarrow as pa
        import pyarrow.parquet as pq

        import pipeline.io.cdr  # noqa: E401,F401
        from pipeline.io import open_log
        from pipeline.io.fields import _latest
        _latest()
        base = _rss_mb()
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            _reset_peak()
            with open_log(path) as reader:
                reader.topics()
                result = reader.read(REQUESTS)
            read_peak = _peak_mb()
            for topic, data in result.topics.items():
                cols = {"log_ns": data.log_ns, **({"header_ns": data.header_ns} if data.header_ns is not None else {}),
                        **data.columns}
                pq.write_table(pa.table(cols), Path(tmp) / (topic.strip("/").replace("/", "_") + ".parquet"))
            seconds = time.perf_counter() - start
        count = sum(d.read for d in result.topics.values())
        arrays = sum(d.log_ns.nbytes + (d.header_ns.nbytes if d.header_ns is not None else 0)
                     + sum(c.nbytes for c in d.columns.values()) for d in result.topics.values())
        extra = {"paths": {t: d.path for t, d in result.topics.items()}, "failed": result.failed,
                 "arrays_mb": arrays / 1e6, "base_rss_mb": base, "read_peak_mb": read_peak}
    else:
        from ingest import rosbags_reference  # bench/ingest.py

        seconds, count = rosbags_reference(path, method, ros1)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {"method": method, "seconds": seconds, "messages": count, "peak_rss_mb": peak, **extra}


def _child(method: str, path: Path, ros1: bool) -> dict[str, Any]:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--measure", method, "--path", str(path)]
    if ros1:
        cmd.append("--ros1")
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                          check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{method} on {path} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _size_mb(path: Path) -> float:
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else [path]
    return sum(p.stat().st_size for p in files) / 1e6


def logs_in(outdir: Path, minutes: float, formats: list[str]) -> dict[str, dict[str, Path]]:
    """The generated logs under ``outdir`` (written by bench/ingest.py's generator when absent)."""
    from ingest import generate

    marker = outdir / f"generated-{minutes:g}min.json"
    if marker.exists():
        known = {f: {k: Path(v) for k, v in p.items()} for f, p in json.loads(marker.read_text()).items()}
        if all(f in known for f in formats):
            return {f: known[f] for f in formats}
    outdir.mkdir(parents=True, exist_ok=True)
    for sub in ("ros2_mcap", "mcap_zstd", "ros2_sqlite3", "trial.bag"):
        target = outdir / sub
        if target.exists():
            raise SystemExit(f"{target} exists but no {marker.name}: use an empty --logs directory")
    start = time.perf_counter()
    logs = generate(outdir, minutes, [f for f in FORMATS if f in formats])
    print(f"generated {minutes:g} min in {time.perf_counter() - start:.0f} s under {outdir}", flush=True)
    marker.write_text(json.dumps({f: {k: str(v) for k, v in p.items()} for f, p in logs.items()}))
    return {f: logs[f] for f in formats}


HEAD = ("| format | MB | messages | auvid s | MB/s | msgs/s | raw s | deser s | × raw | × deser | arrays MB "
        "| peak RSS MB: read / +Parquet (base) | raw / deser RSS MB | paths |")


def row_md(fmt: str, size: float, a: dict[str, Any], r: dict[str, Any], d: dict[str, Any]) -> str:
    paths = ",".join(sorted(set(a["paths"].values())))
    return (f"| {fmt} | {size:.1f} | {a['messages']} | {a['seconds']:.3f} | {size / a['seconds']:.0f} | "
            f"{a['messages'] / a['seconds']:,.0f} | {r['seconds']:.2f} | {d['seconds']:.2f} | "
            f"{r['seconds'] / a['seconds']:.1f} | {d['seconds'] / a['seconds']:.1f} | {a['arrays_mb']:.1f} | "
            f"{a.get('read_peak_mb', float('nan')):.0f} / {a['peak_rss_mb']:.0f} ({a['base_rss_mb']:.0f}) | "
            f"{r['peak_rss_mb']:.0f} / {d['peak_rss_mb']:.0f} | "
            f"{paths} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS))
    parser.add_argument("--logs", type=Path, default=None, help="generate into / reuse logs from this directory")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--skip-rosbags", action="store_true", help="measure auvid only")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--measure", choices=("auvid", "raw", "deser"), help=argparse.SUPPRESS)
    parser.add_argument("--path", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--ros1", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:
        print(json.dumps(measure(args.measure, args.path, args.ros1)))
        return 0
    outdir = args.logs or Path(tempfile.mkdtemp(prefix="auvid-bench-fast-"))
    logs = logs_in(outdir, args.minutes, args.formats)
    print(HEAD)
    print("|" + "---|" * (HEAD.count("|") - 1), flush=True)
    rows = []
    for fmt, paths in logs.items():
        ros1 = fmt == "ros1"
        runs: dict[str, list[dict[str, Any]]] = {"auvid": [], "raw": [], "deser": []}
        for _ in range(args.repeat):
            for method in ("auvid",) if args.skip_rosbags else ("auvid", "raw", "deser"):
                runs[method].append(_child(method, paths["auvid" if method == "auvid" else "rosbags"], ros1))
        med = {}
        for method, got in runs.items():
            if not got:
                med[method] = {"seconds": float("nan"), "peak_rss_mb": float("nan"), "messages": 0}
                continue
            pick = sorted(got, key=lambda m: m["seconds"])[len(got) // 2]
            med[method] = {**pick, "seconds": statistics.median(m["seconds"] for m in got),
                           "peak_rss_mb": max(m["peak_rss_mb"] for m in got)}
        size = _size_mb(paths["auvid"])
        print(row_md(fmt, size, med["auvid"], med["raw"], med["deser"]), flush=True)
        rows.append({"format": fmt, "size_mb": size, "minutes": args.minutes, **med, "runs": runs})
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
