"""What a positioned read costs as a function of where it lands in the page (issue 15, fourth round).

    python bench/read_phase.py /tmp/ib60/ros2_sqlite3/ros2_sqlite3.db3      # any large file, warm in the page cache
    taskset -c 0 python bench/read_phase.py FILE --mb 16 --repeat 5

Reads the file's first ~200 MB with ``os.preadv`` in pieces of ``--mb`` MB into one reused buffer, the way the
batched readers do, for several (file offset, destination) phases in the 4 KiB page, and prints the CPU time of
each (min of ``--repeat``) beside the read at equal phases. A large numpy array starts 16 bytes into a page, so a
page-aligned read into it (every sqlite page read) is the "dest +16" row; ``pipeline.io.base.aligned_empty``
places each read at its file offset's phase instead (the "equal" rows).
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--mb", type=int, default=16, help="bytes a read, MB (the readers' batch: 16)")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
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
