"""The sixth round's knobs, each measured in one process with its settings interleaved (CPU s, min of N):

    taskset -c 0 python bench/ingest_knobs.py parquet /tmp/ib60/ros2_mcap           # the streams' Parquet encodings
    taskset -c 0 python bench/ingest_knobs.py batch /tmp/ib60/ros2_mcap /tmp/ib60/trial.bag   # indexed batch size
    taskset -c 0 python bench/ingest_knobs.py window /tmp/ib240/ros2_mcap/ros2_mcap.mcap      # index-walk window

``parquet``: the tables ``ingest_log`` builds from the log, written with plain encodings and with
:func:`pipeline.tableio.column_encodings` (zstd level 1 both), every file read back and compared; ``batch``:
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


def best_of(settings: dict[str, Callable[[], Any]], repeat: int) -> dict[str, float]:
    """Min CPU seconds of each setting, the settings taking turns."""
    best = {name: float("inf") for name in settings}
    for _ in range(repeat):
        for name, fn in settings.items():
            start = time.process_time()
            fn()
            best[name] = min(best[name], time.process_time() - start)
    return best


def parquet(log: Path, repeat: int) -> None:
    import ingest as bench
    import pyarrow.parquet as pq

    from pipeline.ingest import ingest_log
    from pipeline.tableio import column_encodings

    tables = ingest_log(log, bench.bench_vehicle(), checksum="none").tables
    sizes: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        def write(name: str, encoded: bool) -> None:
            total = 0
            for stream, table in tables.items():
                path = Path(tmp) / f"{stream}-{name}.parquet"
                extra = {"column_encoding": column_encodings(table.schema)} if encoded else {}
                pq.write_table(table, path, compression="zstd", compression_level=1, use_dictionary=False,
                               write_statistics=True, store_schema=True, **extra)
                total += path.stat().st_size
            sizes[name] = total

        best = best_of({"plain": lambda: write("plain", False), "encoded": lambda: write("encoded", True)}, repeat)
        for stream, table in tables.items():
            back = pq.read_table(Path(tmp) / f"{stream}-encoded.parquet")
            assert back.equals(table), stream
    print(f"{log}: {sum(t.num_rows for t in tables.values()):,} rows in {len(tables)} streams")
    print("| encodings | CPU s to write | MiB |\n|---|---|---|")
    for name in best:
        print(f"| {name} | {best[name]:.3f} | {sizes[name] / 2**20:.1f} |")


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
