"""``auvid run``, ``auvid demo`` and one subcommand per stage: the DAG's stages in order, with progress, per-stage
lines and one summary line."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from pipeline import layout
from pipeline.cli.common import (
    EXIT_OK,
    EXIT_QUARANTINED,
    UsageError,
    check_paths,
    on_stage,
    print_stage,
    progress_factory,
    salvaged,
)
from pipeline.errors import ConfigError


def _with_overrides(params: Any, args: argparse.Namespace) -> Any:
    """Params with the command line's overrides (``--no-checksum``: ``ingest.checksum: none``)."""
    checksum = getattr(args, "checksum", None)
    if checksum is None or checksum == params.ingest.checksum:
        return params
    return params.model_copy(update={"ingest": params.ingest.model_copy(update={"checksum": checksum})})


def _vehicle_path(args: argparse.Namespace) -> Path:
    if args.vehicle is not None:
        return args.vehicle
    here = Path("vehicle.yaml")
    return here if here.exists() or not (args.root / "vehicle.yaml").exists() else args.root / "vehicle.yaml"


def _load(args: argparse.Namespace, stages: list[str]) -> tuple[Any, Any]:
    from stages.common import load_configs

    return load_configs(args.root, _vehicle_path(args), args.params, snapshot=stages == ["ingest"])


def _exit_code(results: list[Any]) -> int:
    return EXIT_QUARANTINED if any(r.quarantined for r in results) else EXIT_OK


def _summary(command: str, stages: list[str], results: list[Any], seconds: float, report: Path | None = None) -> str:
    """The one line every stage-running command ends with (the only line with -q)."""
    code = _exit_code(results)
    parts = [f"{len(results)} stage(s) in {seconds:.1f} s"]
    if len(results) < len(stages):
        parts.append(f"stopped after {results[-1].stage if results else 'nothing'}: no trial left to process")
    for r in results:
        if r.quarantined:
            names = [str(e.get("trial") or e.get("model") or e.get("file")) for e in r.quarantined]
            parts.append(f"{r.stage}: {len(names)} quarantined ({', '.join(names)})")
        if salvaged(r):
            parts.append(f"{r.stage}: {len(salvaged(r))} salvaged ({', '.join(salvaged(r))})")
    skipped: dict[str, list[str]] = {}
    for r in results:
        if r.summary.get("skipped"):
            skipped.setdefault(str(r.summary["skipped"]), []).append(r.stage)
    parts += [f"{', '.join(names)} skipped: {reason}" for reason, names in skipped.items()]
    if report is not None:
        parts.append(f"report: {report}")
    status = "done" if code == EXIT_OK else "done with quarantined inputs or failed models"
    return f"auvid {command}: {status} (exit {code}): " + "; ".join(parts)


def _check_inputs(args: argparse.Namespace, stages: list[str]) -> None:
    """Usage errors found before any stage runs: missing logs, nothing to process, an unknown --trial."""
    from stages.common import PER_TRIAL, trials_for

    root = Path(args.root)
    logs = list(getattr(args, "logs", None) or [])
    check_paths(logs, "log(s)")
    if stages[0] == "ingest" and not logs:
        from stages.ingest import discover_logs

        if not discover_logs(root):
            raise UsageError(f"nothing to process: no log given and none under {root / 'data' / 'raw'}")
    elif stages[0] in PER_TRIAL:
        have = trials_for(stages[0], root)
        trial = getattr(args, "trial", None)
        if not have:
            raise UsageError(f"nothing to process: stage {stages[0]} has no input trial under {root} "
                             "(run the stages before it first)")
        if trial is not None and trial not in have:
            raise UsageError(f"stage {stages[0]} has no input for trial {trial!r}; available: {have}")


def _known_trials(args: argparse.Namespace, stages: list[str]) -> set[str]:
    """The trials a run that reaches the features stage can have: the logs given and those under data/raw/, the
    trials ingested (data/signals/) or derived before (what the features stage checks, known before it runs)."""
    from pipeline.ingest import trial_id
    from stages.common import discover_trials
    from stages.ingest import discover_logs

    root = Path(args.root)
    logs = list(getattr(args, "logs", None) or []) if "ingest" in stages else []
    derived = {p.stem for p in (root / layout.DERIVED).glob("*.parquet")}
    return {trial_id(p) for p in [*logs, *discover_logs(root)]} | set(discover_trials(root)) | derived


def _params_file(args: argparse.Namespace) -> Path | None:
    """The params file the run loaded (``--params``, else the run directory's ``params.yaml`` if any)."""
    return args.params or (Path(args.root) / "params.yaml" if (Path(args.root) / "params.yaml").exists() else None)


def _check_model_columns(args: argparse.Namespace, stages: list[str], vehicle: Any, params: Any) -> None:
    """``coupled.inputs`` / ``coupled.outputs`` naming a column the feature store will not have, found before the
    first stage runs (the tune stage refused it only after ingest .. features), naming the store's columns. The
    store's columns are known from the vehicle config and the differentiate method (:func:`store_columns`)."""
    if "tune" not in stages and "train" not in stages:
        return
    from pipeline.config import coupled_skip_reason  # pydantic's loading module: not on ingest's path

    if coupled_skip_reason(vehicle, params) is not None:
        return  # the stages skip the study (and say why)
    from pipeline.store import store_columns

    columns = [c for c in store_columns(vehicle, params.differentiate.method) if c != "split"]
    for key in ("inputs", "outputs"):
        unknown = [c for c in getattr(params.coupled, key) if c not in columns]
        if unknown:
            raise ConfigError(f"coupled.{key} names {unknown}, which the feature store of vehicle {vehicle.name!r} "
                              f"will not have (differentiate.method {params.differentiate.method!r}); its columns: "
                              f"{columns}", file=_params_file(args), field=f"coupled.{key}")


def _check_test_trials(args: argparse.Namespace, stages: list[str], vehicle: Any, params: Any) -> None:
    """Config errors in ``features.test_trials`` found before the first stage runs, naming the trials there are: a
    name that matches none of the run's trials (the features stage would find it only after ingest..derive), and
    none at all in a run that reaches the simulate stage (which rolls the models out on an unseen trial: it would
    fail after the model stages' minutes) unless the vehicle has only the decoupled study (a heave-only ROV:
    simulate then skips, saying why)."""
    where = _params_file(args)
    if "simulate" in stages and not params.features.test_trials:
        from pipeline.config import coupled_skip_reason  # pydantic's loading module: not on ingest's path

        if coupled_skip_reason(vehicle, params) is not None:
            return
        known = sorted(_known_trials(args, stages))
        raise ConfigError("features.test_trials is empty: the simulate stage rolls the models out on an unseen "
                          "trial; name one of this run's trials there" + (f" (its trials: {known})" if known else "")
                          + ", or stop before simulate (--to decoupled)", file=where, field="features.test_trials")
    if "features" not in stages or not params.features.test_trials:
        return
    known = _known_trials(args, stages)
    unknown = [t for t in params.features.test_trials if t not in known]
    if known and unknown:
        raise ConfigError(f"features.test_trials names {unknown}, which match no trial of this run; its trials: "
                          f"{sorted(known)}", file=where, field="features.test_trials")


def cmd_stages(args: argparse.Namespace, stages: list[str]) -> int:
    from stages.common import run_stages

    _check_inputs(args, stages)
    vehicle, params = _load(args, stages)
    params = _with_overrides(params, args)
    _check_test_trials(args, stages, vehicle, params)
    _check_model_columns(args, stages, vehicle, params)
    logs = list(getattr(args, "logs", None) or []) or None
    start = time.perf_counter()
    if getattr(args, "trial", None):
        from pipeline.rootlock import run_root_lock
        from stages.common import call_stage

        with run_root_lock(args.root):
            result = call_stage(stages[0], args.root, vehicle, params, trial=args.trial)
        results = [result]
        if not args.quiet:
            print_stage(stages[0], result, time.perf_counter() - start)
    else:
        results = run_stages(args.root, vehicle, params, stages, logs=logs,
                             progress_factory=progress_factory(args), on_stage=on_stage(args))
    report = Path(args.root) / "reports" / "report.html"
    shown = report.resolve() if "report" in stages and report.exists() else None
    print(_summary(args.command, stages, results, time.perf_counter() - start, shown), flush=True)
    return _exit_code(results)


def cmd_run(args: argparse.Namespace) -> int:
    from stages.common import STAGE_ORDER

    order = list(STAGE_ORDER)
    first = order.index(args.first) if args.first else 0
    last = order.index(args.last) if args.last else len(order) - 1
    if first > last:
        raise ConfigError(f"--from {args.first} comes after --to {args.last} in the DAG")
    return cmd_stages(args, order[first:last + 1])


def cmd_demo(args: argparse.Namespace) -> int:
    from pipeline import demo
    from stages.common import STAGE_ORDER, load_configs, require_stages, run_stages

    require_stages(STAGE_ORDER)  # before minutes of simulation
    out = args.out.resolve()
    start = time.perf_counter()
    say = (lambda *_a, **_k: None) if args.quiet else print
    say(f"auvid demo: simulating the example vehicle into {out}", flush=True)
    setup = demo.prepare(out, duration_s=args.duration_s)
    say(f"  {len(setup.logs)} trial log(s): {', '.join(p.name for p in setup.logs)}")
    say(f"  vehicle config: {setup.vehicle_path}\n  params: {setup.params_path}", flush=True)
    vehicle, params = load_configs(out, setup.vehicle_path, setup.params_path)
    results = run_stages(out, vehicle, params, STAGE_ORDER, logs=setup.logs,
                         progress_factory=progress_factory(args), on_stage=on_stage(args))
    report = out / "reports" / "report.html"
    say(f"demo finished in {time.perf_counter() - start:.0f} s")
    print(_summary("demo", list(STAGE_ORDER), results, time.perf_counter() - start, report), flush=True)
    say(f"report: {report}")
    return _exit_code(results)
