"""The sixth to eighth rounds' knobs, each measured in one process with its settings interleaved (CPU s, min of N):

    taskset -c 0 python bench/ingest_knobs.py parquet /tmp/ib60/ros2_mcap           # the streams' Parquet settings
    taskset -c 0 python bench/ingest_knobs.py batch /tmp/ib60/ros2_mcap /tmp/ib60/trial.bag   # indexed batch size
    taskset -c 0 python bench/ingest_knobs.py window /tmp/ib240/ros2_mcap/ros2_mcap.mcap      # index-walk window
    taskset -c 0 python bench/ingest_knobs.py map /tmp/ib240/ros2_mcap/ros2_mcap.mcap         # preadv or mmap
    taskset -c 0 python bench/ingest_knobs.py hash /tmp/ib60/ros2_mcap/ros2_mcap.mcap         # the sha256's reads

``parquet``: the tables ``ingest_log`` builds from the log, written with plain encodings and with
:func:`pipeline.tableio.column_encodings` (zstd level 1 both), the encoded ones also with every column OPTIONAL (as
streams were written before the seventh round) beside REQUIRED (as ``ingest_log`` builds them now), every file read
back and compared, min and median of N and in how many of the N rounds REQUIRED was the faster; ``batch``:
``ingest_log`` (``checksum: none``) with the MCAP and ROS 1 indexed readers' batch limit at 2, 4, 8 and 16 MB;
``window``: the MCAP index walk with a positioned read per record and windows of 4 KiB to 256 KiB; ``map``: an
uncompressed MCAP's chunks read in the indexed reader's 4 MB batches and every message record's header gathered
(what ``chunk_batches`` does before decoding), the batches read with ``preadv`` into the page-aligned buffer (as the
reader does) or taken from a memory map of the file (pages given back behind, with and without
``MADV_SEQUENTIAL``); ``hash``: :func:`pipeline.tableio.file_sha256` (a fresh ``bytes`` per 1 MiB read) beside the
same hash fed from one page-aligned buffer (``readinto``), and both reads without the hash.
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


def read_map(log: Path, repeat: int) -> None:
    import mmap

    import numpy as np

    from pipeline.io.base import BATCH_BYTES, scratch_buffer, take_rows
    from pipeline.io.mcap_index import index_walk

    indexed = index_walk(log)
    assert indexed is not None and all(c.compression == "" for c in indexed.chunks), "an indexed, uncompressed MCAP"
    groups, group, size = [], [], 0
    for chunk in indexed.chunks:
        group.append(chunk)
        size += chunk.usize
        if size >= BATCH_BYTES:
            groups, group, size = [*groups, group], [], 0
    groups += [group] if group else []
    # Each batch's message records, as file offsets (every channel: the bench's vehicle wants every topic).
    records = [np.sort(np.concatenate([offs.astype(np.int64) + c.body for c in g for offs in c.index.values()]))
               for g in groups]

    def by_preadv() -> int:
        fd, scratch, seen = os.open(log, os.O_RDONLY), [np.empty(0, dtype=np.uint8)], 0
        try:
            for g, offs in zip(groups, records, strict=True):
                lo, hi = g[0].body, g[-1].body + g[-1].length
                buf = scratch_buffer(scratch, hi - lo, phase=lo)
                os.preadv(fd, [buf], lo)
                seen += int(take_rows(buf, offs - lo, 23)[:, 0].sum())
        finally:
            os.close(fd)
        return seen

    def by_mmap(sequential: bool) -> int:
        seen, done = 0, 0
        with open(log, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            if sequential:
                mm.madvise(mmap.MADV_SEQUENTIAL)
            whole = np.frombuffer(mm, dtype=np.uint8)
            for g, offs in zip(groups, records, strict=True):
                lo, hi = g[0].body, g[-1].body + g[-1].length
                seen += int(take_rows(whole[lo:hi], offs - lo, 23)[:, 0].sum())
                upto = lo - lo % mmap.PAGESIZE
                if upto > done:
                    mm.madvise(mmap.MADV_DONTNEED, done, upto - done)
                    done = upto
            del whole  # the map closes only once no array views it
        return seen

    expected = 5 * sum(len(offs) for offs in records)  # every record's opcode is 0x05
    settings = {"preadv": by_preadv, "mmap": lambda: by_mmap(False), "mmap, sequential": lambda: by_mmap(True)}
    assert all(fn() == expected for fn in settings.values())
    best = best_of(settings, repeat)
    print(f"{log} ({os.path.getsize(log) / 1e6:.0f} MB, {len(groups)} batches): read and gather the record headers")
    print("| " + " | ".join(best) + " |\n" + "|---" * len(best) + "|")
    print("| " + " | ".join(f"{t:.3f}" for t in best.values()) + " |")


def read_hash(log: Path, repeat: int) -> None:
    import hashlib

    from pipeline.io.base import aligned_empty
    from pipeline.tableio import file_sha256

    def aligned(hashed: bool) -> str:
        digest, view = hashlib.sha256(), memoryview(aligned_empty(1 << 20))
        with open(log, "rb", buffering=0) as fh:
            while n := fh.readinto(view):
                if hashed:
                    digest.update(view[:n])
        return digest.hexdigest()

    def fresh_reads() -> None:
        with open(log, "rb") as fh:
            while fh.read(1 << 20):
                pass

    assert aligned(True) == file_sha256(log)
    best = best_of({"file_sha256": lambda: file_sha256(log), "aligned readinto + sha256": lambda: aligned(True),
                    "fresh reads alone": fresh_reads, "aligned reads alone": lambda: aligned(False)}, repeat)
    print(f"{log} ({os.path.getsize(log) / 1e6:.0f} MB): CPU s")
    print("| " + " | ".join(best) + " |\n" + "|---" * len(best) + "|")
    print("| " + " | ".join(f"{t:.3f}" for t in best.values()) + " |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("knob", choices=["parquet", "batch", "window", "map", "hash"])
    parser.add_argument("logs", type=Path, nargs="+")
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args(argv)
    if args.knob == "parquet":
        parquet(args.logs[0], args.repeat)
    elif args.knob == "batch":
        batch(args.logs, args.repeat)
    elif args.knob == "window":
        window(args.logs[0], args.repeat)
    elif args.knob == "map":
        read_map(args.logs[0], args.repeat)
    else:
        read_hash(args.logs[0], args.repeat)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
