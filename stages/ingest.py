"""Stage ingest: every raw log -> ``data/signals/<trial>/<stream>.parquet`` + ``ingest_report.json``.

Logs are the entries of ``data/raw`` (files, bag directories, and directories of CSV files, each one trial) or
the paths given with ``--logs``. A log that raises a :class:`~pipeline.errors.PipelineError`, or whose
ingest has quarantine reasons (a stream that is not ``optional`` failed to decode or is empty), is quarantined:
nothing of it is written, an older output of the same trial is removed (it no longer matches the raw file), and
``data/signals/quarantine.json`` lists it with file, reason, error class, topic, field (and the ingest report
when there is one). The batch goes on. Raw logs are only read.

A trial's outputs appear all or nothing: they are written into a temporary directory beside the target and
moved into place with ``os.replace``. ``python -m stages.ingest --root RUN --vehicle vehicle.yaml [--logs ...]``.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from pipeline import layout
from pipeline.config import Params, Vehicle
from pipeline.errors import PipelineError
from pipeline.ingest import ingest_log, trial_id
from pipeline.parallel import usable_cpus
from pipeline.tableio import write_json, write_parquet
from stages.common import StageResult, stage_main

log = logging.getLogger(__name__)

NAME = "ingest"
QUARANTINE_FILE = "quarantine.json"
_IGNORED = {".gitignore", ".dvcignore", ".DS_Store"}
WRITE_THREADS = 4  # streams of one trial written at once


def discover_logs(root: Path) -> list[Path]:
    """Entries of ``data/raw`` in name order, hidden files and ``*.dvc`` pointers left out."""
    raw = Path(root) / layout.RAW
    if not raw.is_dir():
        return []
    return sorted(p for p in raw.iterdir()
                  if not p.name.startswith(".") and p.name not in _IGNORED and not p.name.endswith(".dvc"))


def _display(path: Path, root: Path) -> str:
    try:
        return Path(os.path.relpath(path.resolve(), Path(root).resolve())).as_posix()
    except ValueError:
        return path.resolve().as_posix()


def _replace_dir(tmp: Path, target: Path) -> None:
    """Move ``tmp`` to ``target``; an existing ``target`` is moved aside first, then deleted."""
    old = None
    if target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
        os.replace(target, old / target.name)
    os.replace(tmp, target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_trial(root: Path, trial: str, tables: dict[str, Any], provenance: dict[str, dict[str, Any]],
                report: dict[str, Any]) -> list[Path]:
    """Write one trial's streams and report atomically (all or nothing); returns the final paths.

    The streams are written by a few threads at once (Parquet encoding and zstd release the GIL), largest first;
    each file's bytes do not depend on that.
    """
    target = layout.signals_dir(root, trial)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{trial}.tmp-", dir=target.parent))
    try:
        order = sorted(tables, key=lambda s: (-tables[s].nbytes, s))
        workers = max(1, min(len(order), usable_cpus(), WRITE_THREADS))
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="parquet") as pool:
            jobs = [pool.submit(write_parquet, tables[s], tmp / f"{s}.parquet", provenance[s]) for s in order]
            for job in jobs:
                job.result()
        write_json(report, tmp / "ingest_report.json")
        _replace_dir(tmp, target)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return [layout.stream_path(root, trial, s) for s in sorted(tables)] + [layout.ingest_report_path(root, trial)]


def ingest_one(root: Path, vehicle: Vehicle, path: Path, trial: str, salvage: bool) -> dict[str, Any]:
    """Ingest and write one log; returns {"trial", "outputs"} or {"trial", "quarantine": entry}."""
    shown = _display(path, root)
    try:
        out = ingest_log(path, vehicle, trial=trial, salvage=salvage, source_name=shown)
    except PipelineError as err:
        entry = {**err.as_dict(), "file": shown, "trial": trial}
        return {"trial": trial, "quarantine": entry}
    if out.quarantine:
        first = out.quarantine[0]
        entry = {"error": "IngestError", "reason": "; ".join(f"{q['stream']}: {q['reason']}" for q in out.quarantine),
                 "file": shown, "trial": trial, "topic": first.get("topic"), "field": None, "report": out.report}
        return {"trial": trial, "quarantine": entry}
    outputs = write_trial(root, trial, out.tables, out.provenance, out.report)
    return {"trial": trial, "outputs": outputs}


def _cleanup_stale(root: Path) -> None:
    parent = Path(root) / layout.SIGNALS
    if parent.is_dir():
        for p in parent.iterdir():
            if p.is_dir() and p.name.startswith(".") and (".tmp-" in p.name or ".old-" in p.name):
                shutil.rmtree(p, ignore_errors=True)


def run(root: Path, vehicle: Vehicle, params: Params, logs: Iterable[Path] | None = None,
        progress: Callable[[str], None] | None = None, n_jobs: int = 1) -> StageResult:
    """Ingest raw logs into per-stream Parquet tables with provenance; quarantine bad files."""
    root = Path(root)
    paths = [Path(p) for p in logs] if logs else discover_logs(root)
    result = StageResult(stage=NAME)
    _cleanup_stale(root)
    jobs: list[tuple[Path, str]] = []
    seen: dict[str, Path] = {}
    for path in paths:
        trial = trial_id(path)
        if trial in seen:
            result.quarantined.append({"error": "IngestError", "file": _display(path, root), "trial": trial,
                                       "topic": None, "field": None,
                                       "reason": f"trial id {trial!r} already taken by {_display(seen[trial], root)}"})
            continue
        if not path.exists():
            result.quarantined.append({"error": "IngestError", "file": _display(path, root), "trial": trial,
                                       "topic": None, "field": None, "reason": "no such file or directory"})
            continue
        seen[trial] = path
        jobs.append((path, trial))
    log.info("ingest: %d log(s)", len(jobs))

    salvage = params.ingest.salvage
    if n_jobs == 1 or len(jobs) < 2:
        outcomes: Iterable[dict[str, Any]] = (ingest_one(root, vehicle, p, t, salvage) for p, t in jobs)
    else:
        from joblib import Parallel, delayed

        outcomes = Parallel(n_jobs=n_jobs, return_as="generator")(
            delayed(ingest_one)(root, vehicle, p, t, salvage) for p, t in jobs)
    for outcome in outcomes:
        trial = outcome["trial"]
        if "quarantine" in outcome:
            entry = outcome["quarantine"]
            log.warning("quarantined %s: %s", entry["file"], entry["reason"])
            result.quarantined.append(entry)
            stale = layout.signals_dir(root, trial)
            if stale.exists():
                shutil.rmtree(stale)
            status = f"{trial}: quarantined"
        else:
            result.outputs.extend(outcome["outputs"])
            status = f"{trial}: {len(outcome['outputs']) - 1} stream(s)"
        log.info("ingest %s", status)
        if progress is not None:
            progress(status)

    ok = sorted(o.parent.name for o in result.outputs if o.name == "ingest_report.json")
    result.summary = {"logs": len(paths), "trials_written": ok,
                      "quarantined": sorted(e["trial"] for e in result.quarantined)}
    qpath = Path(root) / layout.SIGNALS / QUARANTINE_FILE
    write_json({"quarantined": sorted(result.quarantined, key=lambda e: (e["trial"], e["file"])),
                "trials_written": ok}, qpath)
    return result


def _extra(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--logs", type=Path, nargs="+", default=None,
                        help="ingest these logs instead of everything under data/raw")
    parser.add_argument("--n-jobs", dest="n_jobs", type=int, default=1, help="trials ingested in parallel")


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv, extra=_extra)


if __name__ == "__main__":
    raise SystemExit(main())
