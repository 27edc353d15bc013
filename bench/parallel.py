"""Per-trial fan-out benchmark (issue 16, item 4): does the process pool pay, and from how much input on?

    nice python bench/parallel.py                                   # 8 trials of 10 simulated minutes
    nice python bench/parallel.py --trials 8 --minutes 60 --logs /tmp/par60      # the issue's 8 one-hour trials
    nice python bench/parallel.py --sweep --logs /tmp/parsweep      # where the pool starts paying (the threshold)

What is timed is a whole ``auvid run --to derive`` process (ingest, sync, differentiate, derive: the stages that
fan out per log or per trial), started fresh each time, as a user or cron would: wall time, and CPU time (user +
system of the process and of every process below it, pool workers included, sampled every 0.1 s with psutil).
The modes:

* ``serial``: ``AUVID_JOBS=1``, every fan-out inline;
* ``serial1`` (``--modes ... serial1``): the same with one BLAS thread (``OPENBLAS_NUM_THREADS=1``), as the pool's
  workers run: how much of serial's speed comes from its own BLAS threads;
* ``pool``: the local process pool on every usable core, whatever the input size (``AUVID_POOL_MIN_BYTES=0``);
* ``auto``: the default, serial below ``pipeline.parallel.POOL_MIN_BYTES`` of input per fan-out, else the pool
  (worker processes forked from the run's process, one BLAS and one Arrow thread each);
* ``loky`` (``--modes ... loky``): the same with joblib's loky workers instead (``AUVID_POOL_START=loky``: fresh
  interpreters that import the pipeline again; the default before the forked pool, and the fallback where fork
  is not available);
* ``dask`` (``--modes ... dask``): ``--scheduler local``, a Dask LocalCluster with one worker per usable core.

The trials are copies of one simulated DAGON log (``pipeline.sim.example``; the per-trial work does not
depend on what the vehicle did, only on how long it logged), named ``trial01`` ... so that each is its own trial.
``--logs DIR`` keeps the generated log for the next call (a one-hour log takes minutes to simulate). Each mode
runs ``--repeat`` times, interleaved; the table shows medians. ``--sweep`` runs serial and pool over several
trial counts and durations and prints, per stage, its input bytes and its time in both modes (from the run's
per-stage lines): the smallest input at which the pool is faster is where ``POOL_MIN_BYTES`` belongs.
Every run's outputs (all of ``data/`` but the raw logs) are hashed: the table says whether each mode wrote the
same bytes as serial. The tree's ``pipeline`` and ``stages`` are compiled to bytecode first, as an installed copy
is (with ``PYTHONDONTWRITEBYTECODE`` set every process, and every loky worker, would compile them again).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
MODES = {"serial": {"AUVID_JOBS": "1"}, "serial1": {"AUVID_JOBS": "1", **ONE_THREAD},
         "pool": {"AUVID_POOL_MIN_BYTES": "0"}, "auto": {}, "loky": {"AUVID_POOL_START": "loky"},
         "dask": {"AUVID_SCHEDULER": "local"}}
KNOBS = ("AUVID_JOBS", "AUVID_POOL_MIN_BYTES", "AUVID_POOL_START", "AUVID_SCHEDULER", *ONE_THREAD)
STAGE_LINE = re.compile(r"^\[(\w+)\] .* in ([0-9.]+) s$")
PER_TRIAL_DIRS = {"ingest": "data/raw", "sync": "data/signals", "differentiate": "data/synced",
                  "derive": "data/kinematics"}


def compile_sources() -> None:
    """``pipeline`` and ``stages`` to bytecode (``__pycache__``, ignored by git), as ``pip install`` does."""
    import compileall

    for sub in ("pipeline", "stages"):
        compileall.compile_dir(ROOT / sub, quiet=1)


def make_log(cache: Path, seconds: float) -> tuple[Path, Path]:
    """One simulated trial log of ``seconds`` and its vehicle config, generated once into ``cache``."""
    from pipeline.sim import example

    target = cache / f"sim{int(seconds)}s"
    log, vehicle = target / "trial01.mcap", target / "vehicle.yaml"
    if not (log.exists() and vehicle.exists()):
        t0 = time.perf_counter()
        example(target, fmt="mcap", duration_s=seconds, n_trials=1)
        print(f"simulated a {seconds:.0f}-s log in {time.perf_counter() - t0:.0f} s: {log}", file=sys.stderr)
    return log, vehicle


def make_root(work: Path, log: Path, vehicle: Path, n_trials: int) -> Path:
    root = work / f"run_{log.parent.name}_{n_trials}"
    raw = root / "data" / "raw"
    if not raw.is_dir():
        raw.mkdir(parents=True)
        for i in range(n_trials):
            os.link(log, raw / f"trial{i + 1:02d}.mcap") if _same_fs(log, raw) else shutil.copy(log, raw)
        shutil.copy(vehicle, root / "vehicle.yaml")
    return root


def _same_fs(a: Path, b: Path) -> bool:
    return a.stat().st_dev == b.stat().st_dev


def clean(root: Path) -> None:
    """Everything but the raw logs and the vehicle config goes: each run starts from the logs."""
    for item in (root / "data").iterdir():
        if item.name != "raw":
            shutil.rmtree(item)
    shutil.rmtree(root / "reports", ignore_errors=True)


def input_bytes(root: Path) -> dict[str, int]:
    out = {}
    for stage, rel in PER_TRIAL_DIRS.items():
        base = root / rel
        out[stage] = sum(p.stat().st_size for p in base.rglob("*") if p.is_file()) if base.is_dir() else 0
    out["differentiate"] += out["sync"]  # it reads the synced table and the trial's native streams
    return out


def _tree_cpu(proc: subprocess.Popen[bytes], every_s: float = 0.1) -> float:
    """CPU seconds (user + system) of ``proc`` and every process below it (pool workers, Dask nannies), sampled
    every ``every_s`` until it exits: a worker's time counts whether or not its parent waited for it (getrusage
    would miss the workers a pool leaves to exit on their own)."""
    import psutil

    seen: dict[tuple[int, float], float] = {}
    root = psutil.Process(proc.pid)
    while proc.poll() is None:
        try:
            tree = [root, *root.children(recursive=True)]
        except psutil.Error:
            tree = []
        for p in tree:
            try:
                times = p.cpu_times()
                seen[(p.pid, p.create_time())] = times.user + times.system
            except psutil.Error:
                pass
        time.sleep(every_s)
    return sum(seen.values())


def run_once(root: Path, mode: str) -> dict[str, Any]:
    clean(root)
    env = {**{k: v for k, v in os.environ.items() if k not in KNOBS}, **MODES[mode]}
    cmd = [str(Path(sys.executable).with_name("auvid")), "run", "--root", str(root), "--vehicle",
           str(root / "vehicle.yaml"), "--to", "derive"]
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=err, text=True)
        cpu = _tree_cpu(proc)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {proc.returncode}:\n{stdout}\n{stderr}")
    stages = {m.group(1): float(m.group(2)) for m in map(STAGE_LINE.match, stdout.splitlines()) if m}
    return {"wall": wall, "cpu": cpu, "stages": stages, "outputs": outputs_digest(root)}


def outputs_digest(root: Path) -> str:
    """sha256 over every file under ``data/`` but the raw logs: names and bytes, in name order."""
    digest = hashlib.sha256()
    data = root / "data"
    for path in sorted(p for p in data.rglob("*") if p.is_file() and p.relative_to(data).parts[0] != "raw"):
        digest.update(path.relative_to(data).as_posix().encode() + b"\0")
        with path.open("rb") as fh:
            while chunk := fh.read(1 << 20):
                digest.update(chunk)
    return digest.hexdigest()


def measure(root: Path, modes: list[str], repeat: int) -> dict[str, list[dict[str, Any]]]:
    runs: dict[str, list[dict[str, Any]]] = {m: [] for m in modes}
    for _ in range(repeat):
        for mode in modes:
            runs[mode].append(run_once(root, mode))
    return runs


def median(runs: list[dict[str, Any]], key: str, stage: str | None = None) -> float:
    if stage is None:
        return statistics.median(r[key] for r in runs)
    return statistics.median(r["stages"].get(stage, float("nan")) for r in runs)


def cmd_speedup(args: argparse.Namespace, cache: Path, work: Path) -> None:
    from pipeline.parallel import POOL_MIN_BYTES, usable_cpus

    log, vehicle = make_log(cache, args.minutes * 60.0)
    root = make_root(work, log, vehicle, args.trials)
    modes = ["serial", *(m for m in args.modes if m != "serial")]
    runs = measure(root, modes, args.repeat)
    sizes = input_bytes(root)
    print(f"{args.trials} trials x {args.minutes:g} simulated min ({log.stat().st_size / 1e6:.1f} MB each), "
          f"{usable_cpus()} usable cores, load average before/after: {args.load0} / "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}, POOL_MIN_BYTES = {POOL_MIN_BYTES / 1e6:g} MB, "
          f"median of {args.repeat}")
    print()
    print("| mode | wall s | CPU s | cores busy | speed-up (wall, vs serial) | per round | "
          + " | ".join(f"{s} s" for s in PER_TRIAL_DIRS) + " | same bytes as serial |")
    print("|---|---|---|---|---|---|" + "---|" * len(PER_TRIAL_DIRS) + "---|")
    base = median(runs["serial"], "wall")
    reference = runs["serial"][0]["outputs"]
    for mode in modes:
        wall, cpu = median(runs[mode], "wall"), median(runs[mode], "cpu")
        rounds = ", ".join(f"{s['wall'] / r['wall']:.2f}" for s, r in zip(runs["serial"], runs[mode], strict=True))
        same = "yes" if all(r["outputs"] == reference for r in runs[mode]) else "**no**"
        print(f"| {mode} | {wall:.1f} | {cpu:.1f} | {cpu / wall:.2f} | {base / wall:.2f}x | {rounds} | "
              + " | ".join(f"{median(runs[mode], 'stages', s):.1f}" for s in PER_TRIAL_DIRS) + f" | {same} |")
    print()
    print("input per stage (MB): " + ", ".join(f"{s} {b / 1e6:.1f}" for s, b in sizes.items()))


def cmd_sweep(args: argparse.Namespace, cache: Path, work: Path) -> None:
    print("| trials x s | stage | input MB | serial s | pool s | pool/serial |")
    print("|---|---|---|---|---|---|")
    totals = []
    for seconds in args.sweep_seconds:
        log, vehicle = make_log(cache, seconds)
        for n in args.sweep_trials:
            root = make_root(work, log, vehicle, n)
            runs = measure(root, ["serial", "pool"], args.repeat)
            sizes = input_bytes(root)
            for stage in PER_TRIAL_DIRS:
                s, p = median(runs["serial"], "stages", stage), median(runs["pool"], "stages", stage)
                print(f"| {n} x {seconds:g} | {stage} | {sizes[stage] / 1e6:.2f} | {s:.2f} | {p:.2f} | "
                      f"{p / s if s else float('nan'):.2f} |", flush=True)
            totals.append((n, seconds, median(runs["serial"], "wall"), median(runs["pool"], "wall")))
    print()
    print("| trials x s | process wall serial s | process wall pool s |")
    print("|---|---|---|")
    for n, seconds, s, p in totals:
        print(f"| {n} x {seconds:g} | {s:.1f} | {p:.1f} |")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--minutes", type=float, default=10.0, help="simulated minutes per trial")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--logs", type=Path, default=None, help="keep / reuse the simulated logs and run dirs here")
    parser.add_argument("--modes", nargs="+", choices=sorted(MODES), default=["serial", "pool", "auto"])
    parser.add_argument("--sweep", action="store_true", help="serial vs pool per stage over sizes (the threshold)")
    parser.add_argument("--sweep-trials", type=int, nargs="+", default=[2, 4, 8])
    parser.add_argument("--sweep-seconds", type=float, nargs="+", default=[30.0, 120.0, 600.0])
    args = parser.parse_args(argv)
    compile_sources()
    args.load0 = " ".join(f"{x:.2f}" for x in os.getloadavg())
    with tempfile.TemporaryDirectory(prefix="auvid-par-") as tmp:
        cache = args.logs or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        (cmd_sweep if args.sweep else cmd_speedup)(args, cache, cache)


if __name__ == "__main__":
    main()
