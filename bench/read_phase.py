"""What a positioned read costs as a function of where it lands in the page (issue 15, fourth round).

    python bench/read_phase.py /tmp/ib60/ros2_sqlite3/ros2_sqlite3.db3      # any large file, warm in the page cache
    taskset -c 0 python bench/read_phase.py FILE --mb 16 --repeat 5
    taskset -c 0 python bench/read_phase.py --ingest /tmp/ib60/ros2_sqlite3 --vehicle /tmp/ib60/bench-vehicle.yaml

Reads the file's first ~200 MB with ``os.preadv`` in pieces of ``--mb`` MB into one reused buffer, the way the
batched readers do, for several (file offset, destination) phases in the 4 KiB page, and prints the CPU time of
each (min of ``--repeat``) beside the read at equal phases. A large numpy array starts 16 bytes into a page, so a
page-aligned read into it (every sqlite page read) is the "dest +16" row; ``pipeline.io.base.aligned_empty``
places each read at its file offset's phase instead (the "equal" rows).

With ``--ingest LOG`` it runs one ``auvid ingest --no-checksum`` of LOG in this process instead, every batched
reader's ``os.preadv`` watched, and prints each read's phase difference and the reads' CPU in all (one process, one
ingest: a min over repeats in one process would hide the cost, since glibc serves a second large buffer from its
heap at another phase).
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pipeline.io.base import PAGE, aligned_empty  # noqa: E402 - the tree beside this file

#: (file offset mod PAGE, destination mod PAGE, what it is)
CASES = [
    (0, 0, "equal: page-aligned read into a page-aligned buffer"),
    (0, 16, "dest +16: page-aligned read into a numpy array (the readers before)"),
    (0, 8, "dest +8"),
    (0, 24, "dest +24"),
    (0, 64, "dest +64"),
    (1000, 1000, "equal: a read at offset 1000 placed at its phase"),
    (1000, 1016, "dest +16 of an unaligned offset"),
    (1000, 0, "dest -1000"),
]


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def watch_ingest(log: Path, vehicle: Path) -> int:
    """One ``auvid ingest --no-checksum`` in this process, the batched readers' positioned reads timed."""
    import tempfile

    import numpy as np

    from pipeline.cli import main as auvid
    from pipeline.io import mcap_index, rosbag1_index, sqlite_btree

    seen: list[tuple[int, int, float]] = []
    real = os.preadv

    def preadv(fd: int, buffers: list, offset: int) -> int:
        start = cpu()
        n = real(fd, buffers, offset)
        addr = np.frombuffer(buffers[0], dtype=np.uint8).ctypes.data
        seen.append(((addr - offset) % PAGE, n, cpu() - start))
        return n

    for module in (mcap_index, rosbag1_index, sqlite_btree):
        module.os.preadv = preadv
    with tempfile.TemporaryDirectory() as root:
        code = auvid(["ingest", "-q", "--no-checksum", "--root", root, "--vehicle", str(vehicle), str(log)])
    phases = sorted({p for p, _, _ in seen})
    print(f"{log}: {len(seen)} batched reads, {sum(n for _, n, _ in seen) / 1e6:.0f} MB, CPU "
          f"{sum(c for _, _, c in seen):.3f} s; destination - file offset mod 4096: {phases[:8]}"
          f"{' ...' if len(phases) > 8 else ''}")
    return code


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("file", type=Path, nargs="?")
    parser.add_argument("--ingest", type=Path, help="a log: watch the reads of one auvid ingest of it instead")
    parser.add_argument("--vehicle", type=Path, help="the vehicle config for --ingest")
    parser.add_argument("--mb", type=int, default=16, help="bytes a read, MB (the readers' batch: 16)")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    if args.ingest is not None:
        if args.vehicle is None:
            parser.error("--ingest needs --vehicle")
        return watch_ingest(args.ingest, args.vehicle)
    if args.file is None:
        parser.error("give a file (or --ingest LOG --vehicle V)")
    piece = args.mb << 20
    size = os.path.getsize(args.file)
    total = min(size - PAGE, 200 << 20) // piece * piece
    if total <= 0:
        parser.error(f"{args.file} is smaller than one read of {args.mb} MB")
    fd = os.open(args.file, os.O_RDONLY)
    base = aligned_empty(piece + 2 * PAGE)
    base[:] = 0  # the buffer's pages faulted in before any timing
    for offset in range(0, total, piece):  # the file into the page cache
        os.preadv(fd, [base[:piece]], offset)
    rows = []
    for src, dst, what in CASES:
        buf = base[dst:dst + piece]
        best = float("inf")
        for _ in range(args.repeat):
            start = cpu()
            for offset in range(0, total, piece):
                os.preadv(fd, [buf], offset + src)
            best = min(best, cpu() - start)
        rows.append((src, dst, what, best))
    os.close(fd)
    ref = rows[0][3]
    print(f"{args.file}: {total / 1e6:.0f} MB in reads of {args.mb} MB, CPU s min of {args.repeat}\n")
    print("| file offset mod 4096 | destination mod 4096 | case | CPU s | ÷ equal phases |")
    print("|---|---|---|---|---|")
    for src, dst, what, best in rows:
        print(f"| {src} | {dst} | {what} | {best:.3f} | {best / ref:.1f}× |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
