"""Generated configs run to the end (issue 36, item 3): ``auvid run`` on a tiny simulated trial set, in a
subprocess under CPU, address-space and wall limits, and its outcome classified. Shared by the in-suite run test
(``tests/config/test_config_runs.py``) and the long campaign (``bench/fuzz_configs.py --run``).

The raw logs (three 40-s simulated trials, ``trial03`` the test trial ``params.yaml`` names; ``trial02`` a directory
of CSV exports with a tank table, read with the vehicle's ``csv:`` options, the others MCAP) are written once per
campaign and hard-linked into each run directory (ingest never modifies them). A params config whose edits
touch the model sections runs to ``report``, with the keys the edits did not touch made cheap (:data:`CHEAP`);
every other config runs to ``derive``.

Outcomes: ``refused`` (exit 2 naming the config file and a key), ``unnamed`` (exit 2 without both), ``ran-ok``
(exit 0, no nonsense), ``quarantine`` (exit 1, the README's "done with quarantined inputs or failed models"),
``stage-failed`` (exit 3, one line), ``traceback`` (a Python traceback on stderr, or an exit code the README does
not define), ``hang`` (the wall timeout or the CPU limit), ``memory`` (an allocation refused under the
address-space limit), ``nonsense`` (exit 0 with one of :func:`nonsense`'s findings).
"""

from __future__ import annotations

import copy
import json
import math
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from tests.config.strategies import CSV_TRIAL, PARAMS, ROOT, VEHICLE, write

RUN_OUTCOMES = ["refused", "unnamed", "ran-ok", "quarantine", "stage-failed", "traceback", "hang", "memory",
                "nonsense"]
GOOD = {"refused", "ran-ok", "quarantine", "stage-failed"}
MODEL_SECTIONS = ("features", "coupled", "decoupled", "simulate")
# Cheap settings for the keys an edit did not touch: a model run in ~15 s instead of ~60 s (the nested search)
CHEAP: dict[tuple[str, str], Any] = {
    ("coupled", "tuning"): "split", ("coupled", "max_evals"): 4, ("coupled", "max_samples"): 300,
    ("coupled", "tuning_folds"): 2, ("coupled", "folds"): 2, ("decoupled", "max_samples"): 200,
    ("decoupled", "gp_max_samples"): 50, ("decoupled", "folds"): 2, ("simulate", "band_samples"): 2}
DEFINED_EXITS = {0, 1, 2, 3}  # README: 130 and 141 are a Ctrl-C and a closed pipe, neither sent here
LIMITS = {"cpu_s": 120, "memory_bytes": 3 << 30, "derive_wall_s": 60.0, "report_wall_s": 180.0}
# Derived columns every written row has (model inputs and targets; the features stage copies them as they are)
_ALWAYS_FINITE = re.compile(r"^([uvwpqr](_smooth)?_(mps|radps)|[uvwpqr]dot_(mps2|radps2)|(roll|pitch|yaw)_rad"
                            r"|(tau|Mnudot|Cnu|g|d)_[uvwpqr]_(N|Nm)|T_.+_N)$")


def raw_logs(directory: Path, duration_s: float = 40.0, seed: int = 1) -> list[Path]:
    """The campaign's raw logs: three simulated trials (``trial01`` .. ``trial03``) written once; ``trial02``
    (:data:`strategies.CSV_TRIAL`) as a directory of CSV exports, one per stream, with a ``tank.csv`` that the
    vehicle's ``tank`` stream reads, as a user with logs of mixed formats has them."""
    import pandas as pd

    from pipeline.sim import generate_trial, load_example_vehicle
    from pipeline.sim.example_logs import example
    from pipeline.sim.writers import write_trial

    logs = example(directory, fmt="mcap", duration_s=duration_s, seed=seed, n_trials=3).trials
    i = [p.stem for p in logs].index(CSV_TRIAL)  # the same trial example() simulated, written as CSV instead
    trial = generate_trial(load_example_vehicle(), duration_s=duration_s, seed=seed * 1000 + i,
                           start_offset_s=3600.0 * i)
    logs[i].unlink()
    logs[i] = write_trial(trial, "csv", directory / CSV_TRIAL)
    ahrs = pd.read_csv(logs[i] / "ahrs.csv")  # the quaternion the vehicle's ahrs_quat reads, beside the Euler angles
    for axis in "xyzw":
        ahrs[f"orientation.{axis}"] = trial.streams["ahrs"].fields[f"orientation.{axis}"]
    ahrs.to_csv(logs[i] / "ahrs.csv", index=False, float_format="%.17g", lineterminator="\n")
    t_s = np.arange(0.0, duration_s, 0.1)  # the tank's tracker: seconds since tank.csv.epoch_s, 10 Hz
    tank = VEHICLE["streams"]["tank"]["csv"]
    start_s = (trial.streams["ahrs"].header_ns[0] / 1e9) - tank["epoch_s"]
    pd.DataFrame({"t": np.round(start_s + t_s, 3), "x": np.sin(0.1 * t_s)}).to_csv(
        logs[i] / "tank.csv", index=False, lineterminator="\n")
    return logs


def touched(what: list[str]) -> list[tuple[str, ...]]:
    """The key paths an edit list (``strategies.edit``'s ``what``) touched."""
    out = []
    for entry in what:
        key = entry[len("drop "):] if entry.startswith("drop ") else \
            entry[len("unknown key beside "):] if entry.startswith("unknown key beside ") else entry.split(" = ")[0]
        out.append(tuple(key.split(".")))
    return out


def run_plan(kind: str, doc: dict[str, Any], what: list[str]) -> tuple[dict[str, Any], dict[str, Any], str]:
    """The (params, vehicle, last stage) a generated config runs with."""
    paths = touched(what)
    if kind == "vehicle":
        return copy.deepcopy(PARAMS), doc, "derive"
    if not any(p[0] in MODEL_SECTIONS for p in paths):
        return doc, copy.deepcopy(VEHICLE), "derive"
    params = copy.deepcopy(doc)
    for (section, key), value in CHEAP.items():
        if isinstance(params.get(section), dict) and key in params[section] and not any(
                p[:len(p)] == (section, key)[:len(p)] for p in paths):
            params[section][key] = value
    return params, copy.deepcopy(VEHICLE), "report"


def _limit(cpu_s: int, memory_bytes: int) -> Any:
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_CPU, (cpu_s, cpu_s + 5))
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    return apply


def run_config(kind: str, doc: dict[str, Any], what: list[str], raw: list[Path], work: Path,
               limits: dict[str, Any] | None = None, to: str | None = None) -> tuple[str, str, float]:
    """Run a generated config on ``raw`` in ``work`` (emptied first) to :func:`run_plan`'s last stage or ``to``:
    its outcome, a detail and the wall time."""
    lim = {**LIMITS, **(limits or {})}
    params, vehicle, last = run_plan(kind, doc, what)
    last = to or last
    if work.exists():
        shutil.rmtree(work)
    (work / "run" / "data" / "raw").mkdir(parents=True)
    for log in raw:  # a CSV trial is a directory: its files linked one by one
        target = work / "run" / "data" / "raw" / log.name
        shutil.copytree(log, target, copy_function=os.link) if log.is_dir() else os.link(log, target)
    ppath, vpath = write(work / "params.yaml", params), write(work / "vehicle.yaml", vehicle)
    config = ppath if kind == "params" else vpath
    env = {**os.environ, "PYTHONPATH": str(ROOT), "AUVID_JOBS": "1", "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONWARNINGS": "default"}
    env.pop("AUVID_SCHEDULER", None)
    cmd = [sys.executable, "-m", "pipeline.cli", "run", "--root", str(work / "run"), "--vehicle", str(vpath),
           "--params", str(ppath), "--to", last]
    wall = lim["report_wall_s"] if last == "report" else lim["derive_wall_s"]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=work,
                            preexec_fn=_limit(lim["cpu_s"], lim["memory_bytes"]), start_new_session=True)
    try:
        out, err = proc.communicate(timeout=wall)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return "hang", f"over {wall:g} s wall (--to {last})", time.monotonic() - t0
    elapsed = time.monotonic() - t0
    return (*classify(proc.returncode, out, err, work / "run", config), elapsed)


def classify(code: int, out: str, err: str, root: Path, config: Path) -> tuple[str, str]:
    """An ``auvid run``'s outcome from its exit code, its output and what it wrote."""
    last = (err.strip().splitlines() or [""])[-1][:300]
    if re.search(r"MemoryError|bad_alloc|Cannot allocate memory|Unable to allocate|out of memory", err):
        return "memory", last
    if code in (-signal.SIGXCPU, -signal.SIGKILL, 128 + signal.SIGXCPU):
        return "hang", f"CPU limit (signal {-code})"
    if "Traceback" in err or code not in DEFINED_EXITS:
        return "traceback", f"exit {code}: {last}"
    if code == 2:
        named = str(config) in err and "field '" in err
        return ("refused" if named else "unnamed"), last
    if code == 3:
        return "stage-failed", last
    if code == 1:
        return "quarantine", last
    found = nonsense(root, err)
    return ("nonsense", found) if found else ("ran-ok", "")


def nonsense(root: Path, err: str) -> str:
    """What an exit-0 run wrote that no user can take as a result ('' if nothing):

    - a derived table or feature-store part with a non-finite model input or target (:data:`_ALWAYS_FINITE`:
      velocities, accelerations, attitude, thrusts and the force terms; every row the derive stage writes has them,
      and the features stage and the models take them as they are);
    - no derived row at all, or an empty feature store, with no warning printed;
    - NaN or an infinity anywhere in an output JSON (not JSON to a strict parser; a number that is not there is
      null, with a ``reason`` beside it where the writer knows why).
    """
    data = root / "data"
    tables = sorted((data / "derived").glob("*.parquet")) + sorted((data / "features").rglob("*.parquet"))
    rows = 0
    for path in tables:
        table = pq.read_table(path)
        rows += table.num_rows
        for name in table.column_names:
            if _ALWAYS_FINITE.match(name):
                values = table.column(name).to_numpy(zero_copy_only=False).astype(float)
                if not np.isfinite(values).all():
                    return f"{path.relative_to(root)}: {name} has {int((~np.isfinite(values)).sum())} non-finite"
    if rows == 0 and "WARNING" not in err:
        return "no derived row and no warning"
    for path in sorted(data.rglob("*.json")):
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as error:
            return f"{path.relative_to(root)}: not JSON ({error})"
        where = _unexplained_nan(doc)
        if where:
            return f"{path.relative_to(root)}: {where} is not finite"
    return ""


def _unexplained_nan(doc: Any, at: str = "") -> str:
    if isinstance(doc, float) and not math.isfinite(doc):
        return at or "<root>"
    if isinstance(doc, dict):
        for key, value in doc.items():
            found = _unexplained_nan(value, f"{at}.{key}" if at else str(key))
            if found:
                return found
    if isinstance(doc, list):
        for i, value in enumerate(doc):
            found = _unexplained_nan(value, f"{at}[{i}]")
            if found:
                return found
    return ""
