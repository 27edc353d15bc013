"""Training cost vs rows (issue 35): the tune and train stages as whole processes, with the code's defaults, on
feature stores of 10 minutes to 8 hours of trials at the store's 10 Hz grid (6,000 to 288,000 rows).

    nice python bench/train_rows.py WORK                               # 10 30 60 120 240 480 minutes
    nice python bench/train_rows.py WORK --minutes 10 30 --exact-up-to 20000

Each size's store is written directly from :func:`pipeline.sim.synthetic.synthetic_frame` (the coupled study's
3-DOF plant, feature-store columns), not through ingest..features: trials of ``--trial-minutes`` (10) each, or
two halves when the total is shorter, the last one held out (``features.test_trials``); the params give nothing
else. Then ``python -m stages.tune`` and ``python -m stages.train`` run as DVC runs them, each a fresh process,
with ``AUVID_JOBS`` workers (default 1: tasks one after the other, so CPU and wall agree) and one BLAS thread.
Per stage: wall s, CPU s (user + sys of the stage's process tree, from ``os.wait4``), peak RSS and each task's
CPU s (``AUVID_TASK_TRACE``: a search chain of tune, a CV fold or final fit of train; in ``results.json``).

Where the store has at most ``--exact-up-to`` rows, train runs again with ``coupled.svr_max_rows: null`` (every
row in every SVR fit) and the table gives the largest |R² difference| on the test trial over the SVR models and
outputs (``metrics.json``'s ``final_r2``), and that run's CPU. ``WORK/results.json`` keeps every figure.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline import store  # noqa: E402
from pipeline.config import Params  # noqa: E402
from pipeline.sim import example_vehicle_path, load_example_vehicle  # noqa: E402
from pipeline.sim.synthetic import synthetic_frame  # noqa: E402
from pipeline.vocabulary import NOISE_STD_COLUMNS  # noqa: E402

RATE_HZ = 10.0
SVRS = ("rbf_svr", "two_weights_svr", "wdse_svr", "graybox")
TEST_SEED = 999
NOISE = 0.02  # synthetic_frame's default measurement noise, a fraction of each signal's SD
SD_OF = ("u_mps", "v_mps", "r_radps", "udot_mps2", "vdot_mps2", "rdot_radps2")  # NOISE_STD_COLUMNS' signals


def trial_plan(total_min: float, trial_min: float) -> list[tuple[str, int, int]]:
    """(trial, seed, rows) per trial: trials of ``trial_min`` (two halves when the total is shorter), the last
    one the test trial (seed 999, so every size is checked on the same motion)."""
    n = max(2, round(total_min / trial_min))
    rows = round(total_min * 60 * RATE_HZ / n)
    plan = [(f"t{k + 1:02d}", k + 1, rows) for k in range(n - 1)]
    return [*plan, ("test", TEST_SEED, rows)]


def write_store(root: Path, total_min: float, trial_min: float) -> int:
    """The feature store of one size under ``root`` (vehicle.yaml and params.yaml beside it); returns its rows."""
    vehicle = load_example_vehicle()
    params = Params(features={"test_trials": ["test"]})
    total = 0
    for k, (trial, seed, rows) in enumerate(trial_plan(total_min, trial_min)):
        frame = synthetic_frame(rows, rate_hz=RATE_HZ, seed=seed, trial=trial, noise=NOISE)
        frame["t_ns"] += int(k * (rows / RATE_HZ + 100.0) * 1e9)  # one trial after the other on the clock
        # the smoother's SDs, as a real store has them (the explicit models' errors-in-variables weights):
        # synthetic_frame's noise, 2 % of each signal's SD
        for name, signal in zip(NOISE_STD_COLUMNS, SD_OF, strict=True):
            frame[name] = NOISE * frame[signal].std()
        frame = frame[[c for c in frame.columns if c in ("t_ns", "segment") or store._column_type(c) is not None]]
        fill = {n: 0.0 for n, _ in store.FIXED_COLUMNS if n != "split" and n not in frame.columns}
        store.write_trial(root, vehicle.name, trial, frame.assign(**fill), params.features, {})
        total += rows
    shutil.copy(example_vehicle_path(), root / "vehicle.yaml")
    (root / "params.yaml").write_text("features:\n  test_trials: [test]\n")
    (root / "params_exact.yaml").write_text("features:\n  test_trials: [test]\ncoupled:\n  svr_max_rows: null\n")
    return total


def run_stage(root: Path, stage: str, params: str, jobs: int) -> dict[str, float]:
    """One stage as its own process; wall s, CPU s of its process tree (pool workers included) and peak RSS MB."""
    env = {**os.environ, "AUVID_JOBS": str(jobs), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    trace = root / f"trace_{stage}_{Path(params).stem}.jsonl"
    trace.unlink(missing_ok=True)
    env["AUVID_TASK_TRACE"] = str(trace)
    cmd = [sys.executable, "-m", f"stages.{stage}", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"),
           "--params", str(root / params)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{err[-3000:]}")
    tasks = [json.loads(line) for line in trace.read_text().splitlines()] if trace.exists() else []
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "rss_mb": usage.ru_maxrss / 1024,
            "tasks_cpu_s": {t["task"]: round(t["cpu_s"], 2) for t in tasks if t["stage"] != "run"}}


def final_r2(root: Path) -> dict[str, dict[str, float]]:
    metrics = json.loads((root / "data/evaluation/coupled/metrics.json").read_text())
    return {m: {o: v["final_r2"] for o, v in per.items()} for m, per in metrics.items() if "failed" not in per}


def measure(work: Path, total_min: float, args: argparse.Namespace) -> dict[str, Any]:
    root = work / f"m{total_min:g}"
    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    t0 = time.perf_counter()
    rows = write_store(root, total_min, args.trial_minutes)
    result: dict[str, Any] = {"minutes": total_min, "rows": rows, "store_s": time.perf_counter() - t0}
    result["train_test_rows"] = len(store.load(root, split="train_test", columns=["t_ns"]))
    for stage in ("tune", "train"):
        result[stage] = run_stage(root, stage, "params.yaml", args.jobs)
        print(f"  {total_min:g} min {stage}: {_brief(result[stage])}", flush=True)
    result["r2"] = final_r2(root)
    if rows <= args.exact_up_to:
        result["train_exact"] = run_stage(root, "train", "params_exact.yaml", args.jobs)
        result["r2_exact"] = final_r2(root)
        print(f"  {total_min:g} min train (exact): {_brief(result['train_exact'])}", flush=True)
    if not args.keep:
        shutil.rmtree(root / "data/features", ignore_errors=True)
    return result


def _brief(r: dict[str, Any]) -> str:
    return f"wall {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s, RSS {r['rss_mb']:.0f} MB"


def worst_difference(r: dict[str, Any]) -> tuple[float, str]:
    """The SVR models' largest |R² (bounded) - R² (exact)| on the test trial, and where."""
    worst, where = 0.0, ""
    for m in SVRS:
        for o, v in r["r2"].get(m, {}).items():
            d = v - r["r2_exact"][m][o]
            if abs(d) >= abs(worst):
                worst, where = d, f"{m} {o}"
    return worst, where


def table(results: list[dict[str, Any]]) -> str:
    lines = ["| minutes | rows | train_test rows | tune CPU s | train CPU s | CPU s / 1000 rows | slope | "
             "peak RSS MB | wall s | exact train CPU s | worst ΔR² (bounded − exact) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    prev = None
    for r in results:
        cpu = r["tune"]["cpu_s"] + r["train"]["cpu_s"]
        slope = (f"{math.log(cpu / prev[1]) / math.log(r['rows'] / prev[0]):.2f}" if prev else "")
        prev = (r["rows"], cpu)
        exact, diff = "", ""
        if "r2_exact" in r:
            exact = f"{r['train_exact']['cpu_s']:.0f}"
            d, where = worst_difference(r)
            diff = f"{d:+.4f} ({where})"
        rss = max(r["tune"]["rss_mb"], r["train"]["rss_mb"])
        wall = r["tune"]["wall_s"] + r["train"]["wall_s"]
        lines.append(f"| {r['minutes']:g} | {r['rows']} | {r['train_test_rows']} | {r['tune']['cpu_s']:.0f} | "
                     f"{r['train']['cpu_s']:.0f} | {1000 * cpu / r['rows']:.2f} | {slope} | {rss:.0f} | "
                     f"{wall:.0f} | {exact} | {diff} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("work", type=Path, help="a scratch directory (one run root per size)")
    parser.add_argument("--minutes", type=float, nargs="+", default=[10, 30, 60, 120, 240, 480])
    parser.add_argument("--trial-minutes", type=float, default=10.0)
    parser.add_argument("--exact-up-to", type=int, default=20_000, help="rows; 0: no exact runs")
    parser.add_argument("--jobs", type=int, default=1, help="AUVID_JOBS of the stage processes")
    parser.add_argument("--keep", action="store_true", help="keep each size's feature store")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    results = []
    for minutes in args.minutes:
        results.append(measure(args.work, minutes, args))
        (args.work / "results.json").write_text(json.dumps(results, indent=1))
        print(table(results), flush=True)


if __name__ == "__main__":
    main()
