"""The sixth and seventh rounds' knobs, each measured in one process with its settings interleaved (CPU s, min of N):

    taskset -c 0 python bench/ingest_knobs.py parquet /tmp/ib60/ros2_mcap           # the streams' Parquet settings
    taskset -c 0 python bench/ingest_knobs.py batch /tmp/ib60/ros2_mcap /tmp/ib60/trial.bag   # indexed batch size
    taskset -c 0 python bench/ingest_knobs.py window /tmp/ib240/ros2_mcap/ros2_mcap.mcap      # index-walk window

``parquet``: the tables ``ingest_log`` builds from the log, written with plain encodings and with
:func:`pipeline.tableio.column_encodings` (zstd level 1 both), the encoded ones also with every column OPTIONAL (as
streams were written before the seventh round) beside REQUIRED (as ``ingest_log`` builds them now), every file read
back and compared, min and median of N and in how many of the N rounds REQUIRED was the faster; ``batch``:
``ingest_log`` (``checksum: none``) with the MCAP and ROS 1 indexed readers' batch limit at 2, 4, 8 and 16 MB;
``window``: the MCAP index walk with a positioned read per record and windows of 4 KiB to 256 KiB.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE)]


def timed(settings: dict[str, Callable[[], Any]], repeat: int) -> dict[str, list[float]]:
    """CPU seconds of each setting in every round, the settings taking turns (in reverse order every other round)."""
    runs: dict[str, list[float]] = {name: [] for name in settings}
    for r in range(repeat):
        for name, fn in (list(settings.items()) if r % 2 == 0 else list(settings.items())[::-1]):
            start = time.process_time()
            fn()
            runs[name].append(time.process_time() - start)
    return runs


def best_of(settings: dict[str, Callable[[], Any]], repeat: int) -> dict[str, float]:
    """Min CPU seconds of each setting, the settings taking turns."""
    return {name: min(times) for name, times in timed(settings, repeat).items()}


def parquet(log: Path, repeat: int) -> None:
    import statistics

    import ingest as bench
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.ingest import ingest_log
    from pipeline.tableio import column_encodings

    tables = ingest_log(log, bench.bench_vehicle(), checksum="none").tables
    optional = {s: t.cast(pa.schema([f.with_nullable(True) for f in t.schema], metadata=t.schema.metadata))
                for s, t in tables.items()}
    sizes: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        def write(name: str, encoded: bool, which: dict[str, Any]) -> None:
            total = 0
            for stream, table in which.items():
                path = Path(tmp) / f"{stream}-{name}.parquet"
                extra = {"column_encoding": column_encodings(table.schema)} if encoded else {}
                pq.write_table(table, path, compression="zstd", compression_level=1, use_dictionary=False,
                               write_statistics=True, store_schema=True, **extra)
                total += path.stat().st_size
            sizes[name] = total

        runs = timed({"plain, optional": lambda: write("plain", False, optional),
                      "encoded, optional": lambda: write("encoded-optional", True, optional),
                      "encoded, required": lambda: write("encoded", True, tables)}, repeat)
        for stream, table in tables.items():
            for name in ("encoded", "encoded-optional"):
                back = pq.read_table(Path(tmp) / f"{stream}-{name}.parquet")
                assert back.cast(table.schema).equals(table), (stream, name)
    files = {"plain, optional": "plain", "encoded, optional": "encoded-optional", "encoded, required": "encoded"}
    paired = sum(a < b for a, b in zip(runs["encoded, required"], runs["encoded, optional"], strict=True))
    print(f"{log}: {sum(t.num_rows for t in tables.values()):,} rows in {len(tables)} streams")
    print("| encodings, columns | CPU s to write, min | median | MiB |\n|---|---|---|---|")
    for name, times in runs.items():
        print(f"| {name} | {min(times):.3f} | {statistics.median(times):.3f} | {sizes[files[name]] / 2**20:.2f} |")
    print(f"REQUIRED faster than OPTIONAL in {paired} of {repeat} rounds")


def batch(logs: list[Path], repeat: int) -> None:
    import ingest as bench

    import pipeline.io.mcap_index as mcap_index
    import pipeline.io.rosbag1_index as rosbag1_index
    from pipeline.ingest import ingest_log

    vehicle = bench.bench_vehicle()
    limits = [2 << 20, 4 << 20, 8 << 20, 16 << 20]

    def run(log: Path, limit: int) -> None:
        mcap_index.chunk_batches.__defaults__ = (limit,)
        rosbag1_index.chunk_batches.__defaults__ = (limit,)
        ingest_log(log, vehicle, checksum="none")

    print("| log | " + " | ".join(f"{lim >> 20} MB" for lim in limits) + " |")
    print("|---|" + "---|" * len(limits))
    for log in logs:
        best = best_of({str(lim): (lambda lim=lim, log=log: run(log, lim)) for lim in limits}, repeat)
        print(f"| {log.name} | " + " | ".join(f"{best[str(lim)]:.3f}" for lim in limits) + " |")


def window(log: Path, repeat: int) -> None:
    import pipeline.io.mcap_index as mcap_index

    init = mcap_index._Window.__init__  # noqa: SLF001
    sizes = [1, 4 << 10, 16 << 10, 64 << 10, 256 << 10]

    def walk(size: int) -> None:
        mcap_index._Window.__init__ = lambda self, fd: init(self, fd, size)  # noqa: SLF001
        assert mcap_index._index_walk(log) is not None  # noqa: SLF001

    best = best_of({str(s): (lambda s=s: walk(s)) for s in sizes}, repeat)
    mcap_index._Window.__init__ = init  # noqa: SLF001
    print(f"{log} ({os.path.getsize(log) / 1e6:.0f} MB): index walk CPU s by window")
    print("| window | " + " | ".join("a read per record" if s == 1 else f"{s >> 10} KiB" for s in sizes) + " |")
    print("|---|" + "---|" * len(sizes))
    print("| CPU s | " + " | ".join(f"{best[str(s)]:.4f}" for s in sizes) + " |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("knob", choices=["parquet", "batch", "window"])
    parser.add_argument("logs", type=Path, nargs="+")
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args(argv)
    if args.knob == "parquet":
        parquet(args.logs[0], args.repeat)
    elif args.knob == "batch":
        batch(args.logs, args.repeat)
    else:
        window(args.logs[0], args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
