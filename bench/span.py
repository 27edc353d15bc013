"""Work, span and speed-up of a run (issue 35, item 5): what more workers could give, beside what 1, 2, ... give.

    nice python bench/span.py models                                  # the demo's tune + train
    nice python bench/span.py derive --trials 16 --minutes 60 --logs /tmp/span60   # 16 one-hour trials, ingest..derive
    nice python bench/span.py models --workers 1 2 4 8 16             # where a machine has the cores
    nice python bench/span.py models --dask                           # ... and on a Dask LocalCluster of as many

Each run is a whole ``auvid run`` process, started fresh, with ``AUVID_TASK_TRACE`` set: every stage and every task
the stages hand to the executor (a log's ingest, a trial's sync / differentiate / derive, each fit or GP of a search
round of tune, a CV fold or final fit of train) records its wall and CPU time (``pipeline.parallel.record_task``).

From the serial run (``AUVID_JOBS=1``: tasks one after the other, undisturbed):

* work = the process's wall time: the stages' (every task and the stages' own serial parts: loading, writing) and
  the process's start and end outside them (imports, configs);
* span = per stage, its serial part (its wall time less its tasks') plus its longest chain of dependent tasks (a
  search's rounds, each as long as its slowest task: ``longest_path``; a task that names no dependency starts with
  its stage), summed over the stages (a stage starts when the one before it ends), plus the process's start and end;
* work / span = the speed-up unlimited workers could give this run.

Then the same run with ``AUVID_JOBS=N`` for each ``--workers`` N: wall time, CPU time of the whole process tree
(pool workers included, sampled with psutil) and speed-up against serial, medians of ``--repeat``. The outputs of
every run are hashed: the table says whether each wrote the same bytes as serial.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.parallel import KNOBS, _tree_cpu, clean, compile_sources, make_log, make_root  # noqa: E402

MODEL_STAGES = ("tune", "train")


def longest_path(tasks: list[dict[str, Any]]) -> float:
    """The longest chain of dependent tasks, in wall seconds: a task starts when every task of the rounds it names
    in ``deps`` has ended (``"<label> r<k>"`` names round k of a coroutine, :mod:`pipeline.rounds`; a task's own
    name outside rounds), else at its stage's start. Records come in the order the serial run wrote them, each
    after those it depends on."""
    finish: dict[str, float] = {}
    groups: dict[str, float] = defaultdict(float)
    for r in tasks:
        start = max((groups.get(d, finish.get(d, 0.0)) for d in r.get("deps", [])), default=0.0)
        finish[r["task"]] = start + r["wall_s"]
        group = r["task"].rsplit(" #", 1)[0]
        groups[group] = max(groups[group], finish[r["task"]])
    return max(finish.values(), default=0.0)


def span_of(trace: list[dict[str, Any]]) -> dict[str, Any]:
    """Work, span and per-stage figures of one serial run's trace (JSON lines of ``record_task``)."""
    stages = [r for r in trace if r["stage"] == "run"]
    tasks: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in trace:
        if r["stage"] != "run":
            tasks[r["stage"]].append(r)
    rows, work, span = [], 0.0, 0.0
    for r in stages:
        own = tasks.get(r["task"], [])
        serial_part = max(0.0, r["wall_s"] - sum(t["wall_s"] for t in own))
        longest = longest_path(own)
        rows.append({"stage": r["task"], "wall_s": r["wall_s"], "tasks": len(own), "serial_s": serial_part,
                     "longest_task_s": longest, "span_s": serial_part + longest})
        work += r["wall_s"]
        span += serial_part + longest
    return {"work_s": work, "span_s": span, "work_over_span": work / span if span else float("nan"),
            "stages": rows}


TIMED = {"search_trace.json", "timings.json"}  # wall / CPU seconds: they differ from run to run


def outputs_digest(root: Path) -> str:
    """sha256 over every file under ``data/`` but the raw logs and the files that record time."""
    import hashlib

    digest = hashlib.sha256()
    data = root / "data"
    for path in sorted(p for p in data.rglob("*") if p.is_file() and p.relative_to(data).parts[0] != "raw"
                       and p.name not in TIMED):
        digest.update(path.relative_to(data).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def run_once(root: Path, args: list[str], jobs: int, dask: bool = False) -> dict[str, Any]:
    trace = Path(tempfile.mkstemp(suffix=".jsonl")[1])
    env = {**{k: v for k, v in os.environ.items() if k not in KNOBS}, "AUVID_JOBS": str(jobs),
           "AUVID_TASK_TRACE": str(trace)}
    if dask:  # a LocalCluster of `jobs` one-thread workers, started by the run
        env["AUVID_SCHEDULER"] = f"local:{jobs}"
    cmd = [str(Path(sys.executable).with_name("auvid")), "run", "--root", str(root), *args]
    with tempfile.TemporaryFile("w+") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, text=True)
        cpu = _tree_cpu(proc)
        wall = time.perf_counter() - t0
        out.seek(0)
        text = out.read()
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {proc.returncode}:\n{text}")
    records = [json.loads(line) for line in trace.read_text().splitlines() if line.strip()]
    trace.unlink()
    return {"wall": wall, "cpu": cpu, "trace": records, "outputs": outputs_digest(root)}


def models_root(work: Path) -> tuple[Path, list[str]]:
    """The demo's run directory through features (once), and the arguments of a tune + train run on it."""
    from pipeline.demo import prepare

    root = work / "auvid-demo"
    common = ["--vehicle", str(root / "vehicle.yaml"), "--params", str(root / "params.yaml")]
    if not (root / "data" / "features").is_dir():
        setup = prepare(root)
        subprocess.run([str(Path(sys.executable).with_name("auvid")), "run", "--root", str(root),
                        "--vehicle", str(setup.vehicle_path), "--params", str(setup.params_path), "--to", "features"],
                       check=True, stdout=subprocess.DEVNULL)
    return root, [*common, "--from", "tune", "--to", "train"]


def reset_models(root: Path) -> None:
    for sub in ("models", "evaluation"):
        shutil.rmtree(root / "data" / sub, ignore_errors=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=["models", "derive"])
    parser.add_argument("--trials", type=int, default=16, help="derive: trials (copies of one simulated log)")
    parser.add_argument("--minutes", type=float, default=60.0, help="derive: simulated minutes per trial")
    parser.add_argument("--logs", type=Path, default=None, help="keep / reuse the simulated log and run dirs here")
    parser.add_argument("--workers", type=int, nargs="+", default=[2])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--dask", action="store_true", help="also each --workers N on a Dask LocalCluster of N")
    args = parser.parse_args(argv)
    compile_sources()
    work = args.logs or Path(tempfile.mkdtemp(prefix="auvid-span-"))
    work.mkdir(parents=True, exist_ok=True)
    if args.what == "derive":
        log, vehicle = make_log(work / "cache", args.minutes * 60.0)
        root = make_root(work, log, vehicle, args.trials)
        run_args, reset = ["--vehicle", str(root / "vehicle.yaml"), "--to", "derive"], clean
        title = f"{args.trials} trials of {args.minutes:g} min, auvid run --to derive"
    else:
        root, run_args = models_root(work)
        reset, title = reset_models, "the demo's tune + train, auvid run --from tune --to train"
    modes = [(1, False), *[(n, False) for n in args.workers], *[(n, True) for n in args.workers if args.dask]]
    runs: dict[tuple[int, bool], list[dict[str, Any]]] = {m: [] for m in modes}
    for _ in range(args.repeat):
        for n, dask in runs:
            reset(root)
            runs[n, dask].append(run_once(root, run_args, n, dask))
    serial = runs[1, False]
    shape = span_of(serial[0]["trace"])
    # the process's start (imports, configs) and end, outside every stage: serial in any run
    outside = max(0.0, serial[0]["wall"] - shape["work_s"])
    shape["stages"].insert(0, {"stage": "(process start and end)", "wall_s": outside, "tasks": 0, "serial_s": outside,
                               "longest_task_s": 0.0, "span_s": outside})
    shape["work_s"] += outside
    shape["span_s"] += outside
    shape["work_over_span"] = shape["work_s"] / shape["span_s"]
    print(f"# {title}\n")
    print("| stage | serial wall s | tasks | serial part s | longest chain s | span s |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in shape["stages"]:
        print(f"| {r['stage']} | {r['wall_s']:.1f} | {r['tasks']} | {r['serial_s']:.1f} | {r['longest_task_s']:.1f} "
              f"| {r['span_s']:.1f} |")
    print(f"\nwork {shape['work_s']:.1f} s, span {shape['span_s']:.1f} s, work / span {shape['work_over_span']:.1f}\n")
    base = statistics.median(r["wall"] for r in serial)
    print("| workers | wall s (median) | CPU s | speed-up | same bytes as serial |")
    print("| --- | --- | --- | --- | --- |")
    for (n, dask), rs in runs.items():
        wall = statistics.median(r["wall"] for r in rs)
        cpu = statistics.median(r["cpu"] for r in rs)
        same = all(r["outputs"] == serial[0]["outputs"] for r in rs)
        who = f"{n} (Dask LocalCluster)" if dask else str(n)
        print(f"| {who} | {wall:.1f} | {cpu:.1f} | {base / wall:.2f}x | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
