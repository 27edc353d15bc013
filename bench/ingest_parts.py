"""Where one ingest's CPU goes, in one process after its imports (issue 15's floors): the file's sha256, the
storage read alone (the reader's batches, nothing decoded), ``ingest_log`` (read, decode, tables, and the sha256 in
its thread) and ``write_trial`` (the Parquet files); min of N each.

    nice python bench/ingest_parts.py /tmp/ib60/ros2_sqlite3 --repeat 3          # a log bench/ingest.py generated
    nice python bench/ingest_parts.py /tmp/ib60/trial.bag --tree /tmp/before      # another tree's code
    nice python bench/ingest_parts.py /tmp/ib240/ros2_mcap/ros2_mcap.mcap --floor  # the floor beside ``cat``
    nice python bench/ingest_parts.py /tmp/ib240/ros2_mcap/ros2_mcap.mcap --profile 15   # where ingest_log goes

``--floor`` adds what an ingest costs without any decoding, beside ``cat`` of the same file (issue 15's four-hour
target, within 10x of ``cat``): the imports of an ingest of this log (a fresh interpreter, pinned, as
``bench/ingest_ab.py`` measures them) + the storage read alone + ``write_trial``. ``--profile N`` then runs
``ingest_log`` (``checksum: none``) once more under cProfile and prints its N functions of most own time, and the
rows gathered by ``take_rows`` by row width (rows, CPU s, ns a row), and three more calls' user and system CPU
and page faults (``getrusage``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent


def cpu(fn: Callable[[], Any], n: int) -> tuple[float, Any]:
    """Min CPU seconds (every thread of the process) of ``n`` calls, and the last result."""
    best, out = float("inf"), None
    for _ in range(n):
        start = time.process_time()
        out = fn()
        best = min(best, time.process_time() - start)
    return best, out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--tree", type=Path, default=HERE.parent, help="the code tree to measure (default: this)")
    parser.add_argument("--floor", action="store_true", help="also the floor without decoding, beside cat")
    parser.add_argument("--profile", type=int, default=0, metavar="N",
                        help="also ingest_log under cProfile: its N functions of most own time, and the gathers")
    args = parser.parse_args(argv)
    sys.path[:0] = [str(args.tree), str(args.tree / "bench")]
    import ingest as bench

    from pipeline.ingest import ingest_log
    from pipeline.io import open_log
    from pipeline.tableio import file_sha256
    from stages.ingest import write_trial

    vehicle = bench.bench_vehicle()
    path: Path = args.log
    files = [path] if path.is_file() else sorted(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))

    def read_only() -> int:
        with open_log(path) as reader:
            return sum(1 for _ in reader._batches(list(reader.catalog())))  # noqa: SLF001

    def write(out: Any) -> None:
        with tempfile.TemporaryDirectory() as tmp:
            write_trial(Path(tmp), "trial", out.tables, out.provenance, out.report)

    sha, _ = cpu(lambda: [file_sha256(f) for f in files], args.repeat)
    read, batches = cpu(read_only, args.repeat)
    ingest, out = cpu(lambda: ingest_log(path, vehicle), args.repeat)
    written, _ = cpu(lambda: write(out), args.repeat)
    print(f"{path.name} ({args.tree}): sha256 {sha:.3f} | storage read alone {read:.3f} ({batches} batches) | "
          f"ingest_log {ingest:.3f} | write_trial {written:.3f} CPU s, min of {args.repeat}")
    if args.floor:
        import ingest_ab

        with tempfile.TemporaryDirectory() as tmp:
            ingest_ab.CACHE["AUVID_CACHE_DIR"] = str(Path(tmp) / "cache")
            imports, bare, modules = ingest_ab.imports_cpu(str(args.tree), path, bench.vehicle_yaml(Path(tmp)),
                                                           n=args.repeat)
        cat = min(bench.process_cat(path, pin=True)["wall_s"] for _ in range(args.repeat))
        floor = imports + read + written
        print(f"floor without decoding: imports {imports:.3f} ({modules} modules; bare interpreter {bare:.3f}) + "
              f"storage read {read:.3f} + write_trial {written:.3f} = {floor:.3f} s CPU | cat {cat:.3f} s wall | "
              f"floor / cat = {floor / cat:.1f}x (the four-hour target: 10x)")
    if args.profile:
        profile(path, vehicle, args.profile)
    return 0


def profile(path: Path, vehicle: Any, top: int) -> None:
    """``ingest_log`` (no checksum) under cProfile, and every ``take_rows`` call timed by row width."""
    import cProfile
    import pstats
    from collections import defaultdict

    import pipeline.io.base as base
    import pipeline.io.cdr as cdr
    import pipeline.io.mcap_index as mcap_index
    import pipeline.io.rosbag1_index as rosbag1_index
    from pipeline.ingest import ingest_log

    modules = [m for m in (base, cdr, mcap_index, rosbag1_index) if hasattr(m, "take_rows")]
    original = base.take_rows
    gathers: dict[int, list[float]] = defaultdict(lambda: [0, 0.0])

    def timed(buf: Any, at: Any, width: int) -> Any:
        start = time.process_time()
        out = original(buf, at, width)
        gathers[width][0] += len(at)
        gathers[width][1] += time.process_time() - start
        return out

    ingest_log(path, vehicle, checksum="none")  # warm: the file in the page cache, the layouts worked out
    prof = cProfile.Profile()
    prof.runcall(ingest_log, path, vehicle, checksum="none")
    pstats.Stats(prof).sort_stats("tottime").print_stats(top)
    for m in modules:
        m.take_rows = timed
    try:
        ingest_log(path, vehicle, checksum="none")
    finally:
        for m in modules:
            m.take_rows = original
    print("| take_rows width (bytes) | rows | CPU s | ns a row |\n|---|---|---|---|")
    for width, (rows, cpu_s) in sorted(gathers.items()):
        if rows:
            print(f"| {width} | {rows:,} | {cpu_s:.3f} | {1e9 * cpu_s / rows:.0f} |")
    import resource

    print("| ingest_log, again | user s | system s | minor page faults |\n|---|---|---|---|")
    for i in range(3):
        before = resource.getrusage(resource.RUSAGE_SELF)
        ingest_log(path, vehicle, checksum="none")
        after = resource.getrusage(resource.RUSAGE_SELF)
        print(f"| {i + 1} | {after.ru_utime - before.ru_utime:.3f} | {after.ru_stime - before.ru_stime:.3f} | "
              f"{after.ru_minflt - before.ru_minflt:,} |")


if __name__ == "__main__":
    raise SystemExit(main())
