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
import json
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline import layout
from pipeline.config.checks import SAFE_NAME, SAFE_NAME_RULE
from pipeline.errors import ConfigError, PipelineError
from pipeline.ingest import Checksum, ingest_log, trial_id, user_types
from pipeline.io.text import TextLimits
from pipeline.parallel import imap, task_result, timed_task, usable_cpus
from pipeline.tableio import remove_stale_temps, write_json, write_parquet
from stages.common import StageResult, stage_main

if TYPE_CHECKING:  # the configs may be a snapshot's views (pipeline.config.snapshot): no pydantic to ingest
    from pipeline.config import Params, Vehicle

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


def ingest_one(root: Path, vehicle: Vehicle, path: Path, trial: str, salvage: bool,
               checksum: Checksum = "sha256", text_limits: TextLimits | None = None) -> dict[str, Any]:
    """Ingest and write one log; returns {"trial", "outputs"} or {"trial", "quarantine": entry}."""
    shown = _display(path, root)
    try:
        out = ingest_log(path, vehicle, trial=trial, salvage=salvage, source_name=shown, checksum=checksum,
                         text_limits=text_limits)
    except PipelineError as err:
        entry = {**err.as_dict(), "file": shown, "trial": trial}
        return {"trial": trial, "quarantine": entry}
    if out.quarantine:
        first = out.quarantine[0]
        entry = {"error": "IngestError", "reason": "; ".join(f"{q['stream']}: {q['reason']}" for q in out.quarantine),
                 "file": shown, "trial": trial, "topic": first.get("topic"), "field": None, "report": out.report}
        return {"trial": trial, "quarantine": entry}
    outputs = write_trial(root, trial, out.tables, out.provenance, out.report)
    return {"trial": trial, "outputs": outputs, "salvage": out.report.get("salvage"), "file": shown}


def _ingest_job(job: tuple[Path, Vehicle, Path, str, bool, Checksum, TextLimits]) -> dict[str, Any]:
    return ingest_one(*job)


def _cleanup_stale(root: Path) -> None:
    parent = Path(root) / layout.SIGNALS
    if parent.is_dir():
        for p in parent.iterdir():
            if p.is_dir() and p.name.startswith(".") and (".tmp-" in p.name or ".old-" in p.name):
                shutil.rmtree(p, ignore_errors=True)
        remove_stale_temps(parent)  # quarantine.json's


def run(root: Path, vehicle: Vehicle, params: Params, logs: Iterable[Path] | None = None,
        progress: Callable[[str], None] | None = None, n_jobs: int = 1) -> StageResult:
    """Ingest raw logs into per-stream Parquet tables with provenance; quarantine bad files."""
    root = Path(root)
    paths = [Path(p) for p in logs] if logs else discover_logs(root)
    result = StageResult(stage=NAME)
    unmatched = [] if logs else unmatched_overrides(vehicle, [trial_id(p) for p in paths])
    user_types(vehicle)  # a definition directory that is missing, the root or a whole disk: refused once, here
    _cleanup_stale(root)
    jobs: list[tuple[Path, str]] = []
    seen: dict[str, Path] = {}
    for path in paths:
        trial = trial_id(path)
        if not SAFE_NAME.match(trial):  # the trial id names directories: '...mcap' would be trial '..'
            result.quarantined.append({"error": "IngestError", "file": _display(path, root), "trial": None,
                                       "topic": None, "field": None,
                                       "reason": f"the log's name gives trial id {trial!r}, not a safe name "
                                                 f"({SAFE_NAME_RULE}): rename the log"})
            continue
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

    salvage, checksum = params.ingest.salvage, params.ingest.checksum
    limits = TextLimits(params.ingest.text_max_bytes, params.ingest.text_max_lines, params.ingest.text_max_line_bytes)
    # n_jobs > 1: the logs go to worker processes (forked: they start with this process's imports), the
    # outcomes come back in log order as each is ready
    outcomes = imap(timed_task(_ingest_job, NAME),
                    [(root, vehicle, p, t, salvage, checksum, limits) for p, t in jobs], jobs=n_jobs, in_order=True)
    salvaged: list[dict[str, Any]] = []
    for index, timed in outcomes:
        outcome = task_result(timed, NAME, jobs[index][1])
        trial = outcome["trial"]
        if "quarantine" in outcome:
            entry = outcome["quarantine"]
            log.debug("quarantined %s: %s", entry["file"], entry["reason"])  # the shell prints it, once
            result.quarantined.append(entry)
            stale = layout.signals_dir(root, trial)
            if stale.exists():
                shutil.rmtree(stale)
            status = f"{trial}: quarantined"
        else:
            result.outputs.extend(outcome["outputs"])
            status = f"{trial}: {len(outcome['outputs']) - 1} stream(s)"
            if outcome.get("salvage"):
                salvaged.append({"trial": trial, "file": outcome["file"], **outcome["salvage"]})
                status += " (salvaged)"
        log.info("ingest %s", status)
        if progress is not None:
            progress(status)

    ok = sorted(o.parent.name for o in result.outputs if o.name == "ingest_report.json")
    _raise_if_config_sinks_every_log(result.quarantined, ok, len(paths), vehicle)
    # keyed by file: a log whose name gives no safe trial id has trial None
    result.summary = {"logs": len(paths), "trials_written": ok,
                      "quarantined": sorted(e["file"] for e in result.quarantined),
                      "salvaged": sorted(e["trial"] for e in salvaged),
                      **({"unmatched_overrides": unmatched} if unmatched else {})}
    update_quarantine_file(root, [_display(p, root) for p in paths], ok, result.quarantined, salvaged)
    return result


def unmatched_overrides(vehicle: Vehicle, trials: list[str]) -> list[str]:
    """The ``trials:`` keys of the vehicle config that name none of the run's logs: never applied (a typo, a
    renamed log), so each is warned, naming the key, and listed in the stage's summary. A warning, not an error:
    a config kept for logs that are not (yet) in the run must not stop it."""
    from pipeline.config.checks import applies_to

    unmatched = [p for p in vehicle.override_keys() if not any(applies_to(p, t) for t in trials)]
    for pattern in unmatched:
        log.warning("vehicle config: trials.%s matches none of the run's %d log(s) (trial ids %s%s): it is never "
                    "applied", pattern, len(trials), sorted(trials)[:10], " ..." if len(trials) > 10 else "")
    return unmatched


def _raise_if_config_sinks_every_log(quarantined: list[dict[str, Any]], written: list[str], n_logs: int,
                                     vehicle: Vehicle) -> None:
    """Two or more logs, none written, every one stopped by the same configured topic / field: the config is wrong.

    (With one log the log may be the odd one out, so it is quarantined.) Raised as a ConfigError so that the
    shell exits 2 with the cause instead of writing one quarantine entry per log; it names the vehicle file and
    the key there (``streams.depth.topic``) where it can, else the topic and the field.
    """
    if written or n_logs < 2 or len(quarantined) != n_logs:
        return
    keys = {(e.get("error"), e.get("topic"), e.get("field")) for e in quarantined}
    if len(keys) != 1:
        return
    error, topic, fld = next(iter(keys))
    if error != "IngestError" or topic is None or any("report" in e for e in quarantined):
        return
    message = (f"every log ({n_logs}) fails on the same configured source; fix the vehicle config's streams: "
               f"{quarantined[0]['reason']}")
    key = vehicle.source_key(topic, fld)
    if key is None:
        raise ConfigError(message, topic=topic, field=fld)
    raise ConfigError(message, file=vehicle.config_file(), field=key)


def update_quarantine_file(root: Path, files: list[str], written: list[str], quarantined: list[dict[str, Any]],
                           salvaged: list[dict[str, Any]]) -> Path:
    """Merge this call into ``data/signals/quarantine.json``: entries accumulate per log and are replaced only
    when that log (same file) or its trial is ingested again. Entries are keyed by file: a log whose name gives
    no safe trial id is listed with trial None, and two such logs must not replace each other."""
    qpath = Path(root) / layout.SIGNALS / QUARANTINE_FILE
    old: dict[str, Any] = {}
    if qpath.exists():
        try:
            old = json.loads(qpath.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            log.warning("%s is unreadable; starting a new one", qpath)
    again = set(files)
    redone = (set(written) | {e["trial"] for e in quarantined}) - {None}

    def kept(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [e for e in entries if e.get("file") not in again and e.get("trial") not in redone]

    def order(e: dict[str, Any]) -> tuple[str, str]:
        return (str(e.get("file")), str(e.get("trial")))

    doc = {"quarantined": sorted(kept(old.get("quarantined", [])) + quarantined, key=order),
           "salvaged": sorted(kept(old.get("salvaged", [])) + salvaged, key=order),
           "trials_written": sorted((set(old.get("trials_written", [])) - redone) | set(written))}
    write_json(doc, qpath)
    return qpath


def _extra(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--logs", type=Path, nargs="+", default=None,
                        help="ingest these logs instead of everything under data/raw")
    parser.add_argument("--n-jobs", dest="n_jobs", type=int, default=1, help="trials ingested in parallel")


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv, extra=_extra)


if __name__ == "__main__":
    raise SystemExit(main())
