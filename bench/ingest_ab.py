"""Two code trees, interleaved: whole ``auvid ingest`` processes and the imports' CPU (issue 15's before / after).

    git archive OLD pipeline stages bench | tar -x -C /tmp/before      # (mkdir first) a snapshot of each tree
    git archive NEW pipeline stages bench | tar -x -C /tmp/after
    nice python bench/ingest_ab.py --trees before=/tmp/before after=/tmp/after --logs /tmp/ib60 --repeat 3
    (add --no-checksum to compare both trees without the log's sha256)

The logs are those ``bench/ingest.py --logs DIR`` generated (and, with ``--formats mcap-unindexed ros1-unindexed``,
derived) under ``--logs``. Each round runs every format once per tree, the trees taking turns, each child pinned
to core 0 (``taskset -c 0``) with ``PYTHONPATH`` set to its tree; the table shows the min of N for CPU and wall and
the max for peak RSS (bench/ingest.py's lean spawner); each tree's sources are compiled to bytecode first, as an
installed copy is (``bench/ingest.py``'s ``compile_sources``). The imports' CPU is that of a fresh interpreter
importing exactly the modules a tiny ``auvid ingest`` of each tree leaves in ``sys.modules`` (the log:
``--imports-log``, default the one-hour uncompressed MCAP), pinned to core 0, min of 7, the bare interpreter's start
reported beside it. A tree that keeps config snapshots (:mod:`pipeline.config.snapshot`) keeps them in a cache
directory of this run's, written before anything is timed: what every ingest after the first pays.

``--counts`` adds what does not drift with the machine: one whole ``auvid ingest`` of each tree and format under
valgrind's cachegrind (``apt install valgrind``), its user-space instructions and simulated L1 data and last-level
cache misses: the same tree twice differs by 1-2 % (threads, temporary names), against the ±20 % by which this shared
machine's speed drifts within minutes (docs/benchmarks.md), so a change of a few per cent can be seen there first.
What cachegrind does not see (kernel time: page faults, reads; the L2 misses of a buffer larger than L2) the
timings above must then show on their own.

    nice python bench/ingest_ab.py --trees before=/tmp/before after=/tmp/after --logs /tmp/ib60 --repeat 7 \
        --counts --formats ros2-mcap ros1
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import ingest as bench  # noqa: E402 - the bench beside this file

LOGS = {"ros2-mcap": "ros2_mcap", "mcap-zstd": "mcap_zstd/mcap_zstd_0.mcap", "ros2-sqlite3": "ros2_sqlite3",
        "ros1": "trial.bag", "mcap-unindexed": "unindexed/mcap_unindexed.mcap",
        "ros1-unindexed": "unindexed/trial_unindexed.bag"}

PROBE = """
import json, sys, tempfile
from pipeline.cli import main
assert main(['ingest', '-q', '--root', tempfile.mkdtemp(), '--vehicle', {vehicle!r}, {log!r}]) == 0
print('MODULES=' + json.dumps(sorted(sys.modules)))
"""


#: The config snapshots' directory of this run (``AUVID_CACHE_DIR``), removed at exit.
CACHE: dict[str, str] = {}


def imports_cpu(tree: str, log: Path, vehicle: Path, n: int = 7) -> tuple[float, float, int]:
    """(CPU s of importing what an ingest of ``log`` imports, CPU s of a bare interpreter, modules), min of n."""
    env = {**os.environ, "PYTHONPATH": tree, **CACHE}
    for _ in range(2):  # the first writes the config snapshot (a tree that keeps them); the second reads it
        got = subprocess.run([sys.executable, "-c", PROBE.format(vehicle=str(vehicle), log=str(log))], env=env,
                             capture_output=True, text=True, check=True, cwd=tempfile.gettempdir())
    line = next(ln for ln in got.stdout.splitlines() if ln.startswith("MODULES="))
    modules = [m for m in json.loads(line[len("MODULES="):]) if m not in sys.builtin_module_names
               and not m.startswith("__")]
    code = (f"import importlib\nfor m in {modules!r}:\n    try:\n        importlib.import_module(m)\n"
            "    except Exception:\n        pass\n")

    def cpu(args: list[str]) -> float:
        best = float("inf")
        for _ in range(n):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            subprocess.run([*bench.PIN, sys.executable, *args], env=env, check=True, cwd=tempfile.gettempdir())
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            best = min(best, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
        return best

    return cpu(["-c", code]), cpu(["-c", "pass"]), len(modules)


COUNTS = {"I": "I   refs:", "D1": "D1  misses:", "LL": "LL misses:"}


def cachegrind(cmd: list[str], env: dict[str, str]) -> dict[str, int]:
    """Instructions and simulated cache misses of one run of ``cmd`` under cachegrind (user space, every thread)."""
    if shutil.which("valgrind") is None:
        raise SystemExit("--counts needs valgrind (Debian: apt install valgrind)")
    got = subprocess.run(["valgrind", "--tool=cachegrind", "--cache-sim=yes", "--cachegrind-out-file=/dev/null",
                          *cmd], env=env, capture_output=True, text=True, cwd=tempfile.gettempdir())
    if got.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} under cachegrind failed:\n{got.stderr[-3000:]}")
    out = {}
    for key, label in COUNTS.items():
        line = next(ln for ln in got.stderr.splitlines() if label in ln)
        out[key] = int(line.split(label, 1)[1].split()[0].replace(",", ""))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trees", nargs=2, required=True, metavar="NAME=PATH")
    parser.add_argument("--logs", type=Path, required=True)
    parser.add_argument("--formats", nargs="+", choices=list(LOGS), default=list(LOGS))
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--imports-log", type=Path, default=None)
    parser.add_argument("--no-checksum", action="store_true", help="both trees ingest with --no-checksum (no sha256)")
    parser.add_argument("--counts", action="store_true",
                        help="also one ingest of each tree and format under cachegrind: instructions, cache misses")
    args = parser.parse_args(argv)
    trees = dict(t.split("=", 1) for t in args.trees)
    CACHE["AUVID_CACHE_DIR"] = tempfile.mkdtemp(prefix="auvid-ab-cache-")
    atexit.register(shutil.rmtree, CACHE["AUVID_CACHE_DIR"], True)
    for tree in trees.values():
        for entry in tree.split(os.pathsep):
            bench.compile_sources(Path(entry))
    vehicle = bench.vehicle_yaml(args.logs)
    logs = {f: args.logs / LOGS[f] for f in args.formats if (args.logs / LOGS[f]).exists()}
    print(f"load average {bench._loadavg()}", flush=True)
    res: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for round_ in range(-1, args.repeat):  # round -1, untimed: each tree's config snapshot written
        for fmt, log in logs.items():
            for name, tree in trees.items():
                bench.CHILD_ENV = {**os.environ, "PYTHONPATH": tree, **CACHE}
                tmp = tempfile.mkdtemp(prefix="auvid-ab-")
                try:
                    flag = ["--no-checksum"] if args.no_checksum else []
                    got = bench.run_process([*bench.auvid_command(), "ingest", "-q", *flag, "--root", tmp,
                                             "--vehicle", str(vehicle), str(log)], True)
                finally:
                    shutil.rmtree(tmp)
                if round_ >= 0:
                    res.setdefault((fmt, name), []).append(got)
    a, b = trees
    print(f"load average {bench._loadavg()}\n")
    print(f"| format | {a} CPU s | {b} CPU s | {b} ÷ {a}, CPU | CPU s, median {a} / {b} | system CPU s, median "
          f"{a} / {b} | {b} faster, rounds | {a} wall s | {b} wall s | peak RSS MiB {a} / {b} "
          f"| minor page faults, median {a} / {b} |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for fmt in logs:
        x, y = res[(fmt, a)], res[(fmt, b)]

        def low(runs: list[dict[str, Any]], key: str) -> float:
            return min(r[key] for r in runs)

        def mid(runs: list[dict[str, Any]], key: str) -> float:
            return statistics.median(r[key] for r in runs)

        won = sum(q["cpu_s"] < p["cpu_s"] for p, q in zip(x, y, strict=True))
        print(f"| {fmt} | {low(x, 'cpu_s'):.2f} | {low(y, 'cpu_s'):.2f} | {low(y, 'cpu_s') / low(x, 'cpu_s'):.2f} "
              f"| {mid(x, 'cpu_s'):.2f} / {mid(y, 'cpu_s'):.2f} | {mid(x, 'sys_s'):.2f} / {mid(y, 'sys_s'):.2f} "
              f"| {won} of {len(x)} | {low(x, 'wall_s'):.2f} | {low(y, 'wall_s'):.2f} "
              f"| {max(r['rss_mib'] for r in x):.0f} / {max(r['rss_mib'] for r in y):.0f} "
              f"| {mid(x, 'minflt'):,.0f} / {mid(y, 'minflt'):,.0f} |")
    if args.counts:
        print(f"\n| format | {a} instructions M | {b} instructions M | {b} ÷ {a} | {a} D1 misses M "
              f"| {b} D1 misses M | {b} ÷ {a} | LL misses M {a} / {b} |")
        print("|---|---|---|---|---|---|---|---|")
        auvid = bench.auvid_command()
        if Path(auvid[0]).suffix != ".py" and Path(auvid[0]).name == "auvid":
            auvid = [sys.executable, *auvid]  # the console script, run by this interpreter (valgrind follows it)
        for fmt, log in logs.items():
            got = {}
            for name, tree in trees.items():
                tmp = tempfile.mkdtemp(prefix="auvid-ab-")
                try:
                    flag = ["--no-checksum"] if args.no_checksum else []
                    env = {**os.environ, "PYTHONPATH": tree, "PYTHONHASHSEED": "0", **CACHE}
                    got[name] = cachegrind([*auvid, "ingest", "-q", *flag, "--root", tmp, "--vehicle", str(vehicle),
                                            str(log)], env)
                finally:
                    shutil.rmtree(tmp)
            x, y = got[a], got[b]
            print(f"| {fmt} | {x['I'] / 1e6:.1f} | {y['I'] / 1e6:.1f} | {y['I'] / x['I']:.4f} | {x['D1'] / 1e6:.2f} "
                  f"| {y['D1'] / 1e6:.2f} | {y['D1'] / x['D1']:.4f} | {x['LL'] / 1e6:.2f} / {y['LL'] / 1e6:.2f} |",
                  flush=True)
    imports_log = args.imports_log or args.logs / LOGS["ros2-mcap"]
    print()
    for name, tree in trees.items():
        cpu, bare, n = imports_cpu(tree, imports_log, vehicle)
        print(f"imports of an ingest, {name}: {cpu:.3f} s CPU ({n} modules; bare interpreter {bare:.3f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
