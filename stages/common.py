"""What every stage shell shares: arguments, config loading, the result it reports, exit codes.

A stage module defines ``run(root, vehicle, params, **kw) -> StageResult`` (reads inputs, calls the
library, writes outputs) and ``main(argv) = stage_main(NAME, run, argv)``. Exit codes: 0 done, 1 done
with quarantined inputs or failed models (a model stage lists each failed model in ``quarantined`` with its
``model`` and ``reason``; the others are written), 2 usage or config error, 3 a stage failed (PipelineError);
130 interrupted (Ctrl-C), 141 output pipe closed (``auvid ... | head``), both without a traceback.

The registry of stages (``STAGE_ORDER``, ``load_stage``) and the DAG runner without DVC (``run_stages``) live
here too: the ``auvid`` CLI, ``auvid retrain`` and the tests (with fake stages) all go through them.

**Progress**: a stage whose ``run`` accepts ``progress`` gets a callable (or None) and calls it as
``progress(done, total, desc)``: ``done`` units finished so far (absolute, not an increment), ``total``
the number expected (or None), ``desc`` an optional short label (the file or fold being worked on);
``progress("label")`` alone means one more unit done. The CLI turns it into a tqdm bar, quiet when stdout is
not a terminal; the callable also has ``.update(n)`` (increment). Library code never imports tqdm.
A stage whose ``run`` accepts ``n_jobs`` gets ``pipeline.parallel.n_jobs()`` from the runner.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from pipeline.errors import ConfigError, PipelineError, RunRootBusy
from pipeline.parallel import backend
from pipeline.rootlock import run_root_lock

if TYPE_CHECKING:  # pydantic (~0.2 s of CPU) is imported where configs are validated, not by importing a stage
    from pipeline.config import Params, Vehicle

log = logging.getLogger(__name__)

EXIT_OK, EXIT_QUARANTINED, EXIT_USAGE, EXIT_FAILED = 0, 1, 2, 3
EXIT_INTERRUPTED, EXIT_PIPE = 130, 141  # 128 + SIGINT, 128 + SIGPIPE, as a shell reports them

#: The DAG in execution order (``auvid run`` and ``dvc.yaml`` follow it).
STAGE_ORDER: tuple[str, ...] = ("ingest", "sync", "differentiate", "derive", "features", "tune", "train",
                                "decoupled", "simulate", "report")
#: Stages whose work is per trial (``run(..., trial=...)``): fanned out over trials (dvc.yaml: all trials at once).
PER_TRIAL: frozenset[str] = frozenset({"sync", "differentiate", "derive"})


class MissingStageError(PipelineError):
    """A stage module the DAG needs is not there (not written yet, or an incomplete install)."""


@dataclass
class StageResult:
    stage: str
    outputs: list[Path] = field(default_factory=list)
    quarantined: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        return EXIT_QUARANTINED if self.quarantined else EXIT_OK


def skipped_result(name: str, directories: list[Path], stages: tuple[str, ...], reason: str) -> StageResult:
    """The result of a stage with nothing to do on this run: its output directories hold only the marker saying
    why (:mod:`pipeline.skips`), its summary ``{"skipped": reason}`` (the CLI prints it)."""
    from pipeline.skips import write_skip

    log.info("stage %s skipped: %s", name, reason)  # the CLI and stage_main print it
    return StageResult(name, outputs=write_skip(directories, stages, reason), summary={"skipped": reason})


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--root", type=Path, default=Path("."), help="run directory holding data/ (default: .)")
    parser.add_argument("--vehicle", type=Path, default=Path("vehicle.yaml"), help="vehicle config YAML")
    parser.add_argument("--params", type=Path, default=None,
                        help="params YAML (default: params.yaml in the run directory if present)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def load_configs(root: Path, vehicle_path: Path, params_path: Path | None, *,
                 snapshot: bool = False) -> tuple[Vehicle, Params]:
    """The vehicle config and params (default: ``<root>/params.yaml`` if there), validated and checked against each
    other; ``decoupled.dofs`` those the vehicle measures (:func:`pipeline.config.measured_dofs`). ``snapshot`` (a
    run of ingest alone): files validated before by the same code are read back from their snapshot, without
    pydantic (:mod:`pipeline.config.snapshot`); ingest takes the views as it takes the models."""
    if params_path is None and (root / "params.yaml").exists():
        params_path = root / "params.yaml"
    if snapshot:
        from pipeline.config.snapshot import load_for_ingest

        return load_for_ingest(vehicle_path, params_path)
    from pipeline.config import check_params_against_vehicle, load_params, load_vehicle, measured_dofs

    vehicle, params = load_vehicle(vehicle_path), load_params(params_path)
    check_params_against_vehicle(vehicle, params, params_path)
    return vehicle, measured_dofs(vehicle, params, params_path)


def stage_main(name: str, run: Callable[..., StageResult], argv: list[str] | None = None,
               extra: Callable[[argparse.ArgumentParser], None] | None = None) -> int:
    """Parse arguments, load configs, run the stage, print a one-line summary, return the exit code."""
    parser = argparse.ArgumentParser(prog=f"python -m stages.{name}", description=(run.__doc__ or "").strip())
    add_common_arguments(parser)
    if extra is not None:
        extra(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    kwargs = {k: v for k, v in vars(args).items() if k not in {"root", "vehicle", "params", "verbose"}}
    try:
        vehicle, params = load_configs(args.root, args.vehicle, args.params, snapshot=name == "ingest")
        # AUVID_SCHEDULER sends joblib fan-out to a Dask cluster, else local processes
        with run_root_lock(args.root), backend():
            result = run(args.root, vehicle, params, **kwargs)
    except ConfigError as err:
        print(f"config error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except RunRootBusy as err:
        print(f"{name}: {err}", file=sys.stderr)
        return EXIT_USAGE
    except PipelineError as err:
        print(f"{name} failed: {err}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    if result.summary.get("skipped"):
        print(f"{name}: skipped: {result.summary['skipped']}")
        return result.exit_code
    print(f"{name}: {len(result.outputs)} output(s), {len(result.quarantined)} quarantined")
    for entry in result.quarantined:
        print(f"  quarantined {entry.get('file')}: {entry.get('reason')}", file=sys.stderr)
    return result.exit_code


def load_stage(name: str) -> ModuleType:
    """Import ``stages.<name>``; a MissingStageError names the stage if it does not exist or has no ``run``."""
    if name not in STAGE_ORDER and name != "example":
        raise MissingStageError(f"unknown stage {name!r}; the DAG is {', '.join(STAGE_ORDER)}")
    try:
        module = importlib.import_module(f"stages.{name}")
    except ModuleNotFoundError as err:
        if err.name in (f"stages.{name}", "stages"):
            raise MissingStageError(f"stage {name!r} is not available (no module stages/{name}.py)") from None
        raise
    if not callable(getattr(module, "run", None)):
        raise MissingStageError(f"stage {name!r} has no run(root, vehicle, params, ...) function",
                                file=getattr(module, "__file__", None))
    return module


def accepted_kwargs(fn: Callable[..., Any], kwargs: dict[str, Any]) -> dict[str, Any]:
    """The subset of ``kwargs`` that ``fn`` accepts (all of them if it takes ``**kw``)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return dict(kwargs)
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return dict(kwargs)
    return {k: v for k, v in kwargs.items() if k in params}


def call_stage(name: str, root: Path, vehicle: Vehicle, params: Params, **kwargs: Any) -> StageResult:
    """Run one stage's ``run`` with the optional keyword arguments it accepts (``trial``, ``progress``, ...)."""
    module = load_stage(name)
    result = module.run(Path(root), vehicle, params, **accepted_kwargs(module.run, kwargs))
    if not isinstance(result, StageResult):
        raise PipelineError(f"stage {name!r} returned {type(result).__name__}, expected StageResult")
    return result


def merge_results(name: str, results: list[StageResult]) -> StageResult:
    """One StageResult from the per-trial results of a stage."""
    merged = StageResult(stage=name)
    for result in results:
        merged.outputs.extend(result.outputs)
        merged.quarantined.extend(result.quarantined)
        if result.summary:
            merged.summary.setdefault("trials", []).append(result.summary)
    return merged


def discover_trials(root: Path) -> list[str]:
    """Trials that ingest produced under ``data/signals/`` (sorted), the unit of per-trial work."""
    from pipeline.layout import SIGNALS

    base = Path(root) / SIGNALS
    if not base.is_dir():
        return []
    return sorted(p.name for p in base.iterdir() if p.is_dir() and not p.name.startswith("."))


def trials_for(name: str, root: Path) -> list[str]:
    """The trials a per-trial stage has input for: what its predecessor wrote."""
    from pipeline import layout

    root = Path(root)
    if name == "sync":
        return discover_trials(root)
    source = {"differentiate": layout.SYNCED, "derive": layout.KINEMATICS}.get(name)
    if source is None:
        return []
    base = root / source
    return sorted(p.stem for p in base.glob("*.parquet")) if base.is_dir() else []


def _run_trial(job: tuple[str, Path, Vehicle, Params, str]) -> StageResult:
    name, root, vehicle, params, trial = job
    return call_stage(name, root, vehicle, params, trial=trial)


def run_stage(name: str, root: Path, vehicle: Vehicle, params: Params, *, logs: list[Path] | None = None,
              progress: Callable[..., Any] | None = None, fan_out: bool = True,
              trials: list[str] | None = None) -> StageResult:
    """Run one stage of the DAG; per-trial stages fan out over ``trials`` (default: every trial with input)
    through joblib, in the active backend (local processes or a Dask cluster), reporting one progress unit per
    trial as each finishes. Locally, a fan-out (ingest's too) whose input is below
    ``pipeline.parallel.POOL_MIN_BYTES`` runs serially: a process pool would cost more than it gives."""
    from pipeline.parallel import n_jobs, pmap, pool_pays, task_result, timed_task

    root = Path(root)
    module = load_stage(name)
    kwargs: dict[str, Any] = {"progress": progress, "n_jobs": n_jobs()}
    if name == "ingest":
        paths = list(logs) if logs else list(getattr(module, "discover_logs", lambda _root: [])(root))
        if logs is not None:
            kwargs["logs"] = list(logs)
        if progress is not None and paths:  # ingest reports one call per log: tell the bar the total
            progress(0, len(paths))
        if not pool_pays(len(paths), sum(_size(Path(p)) for p in paths), kwargs["n_jobs"]):
            kwargs["n_jobs"] = 1  # small logs: a process pool would cost more than it gives
    if fan_out and name in PER_TRIAL and "trial" in accepted_kwargs(module.run, {"trial": None}):
        trials = trials_for(name, root) if trials is None else trials
        if not trials:
            log.warning("stage %s: no trial has input yet", name)
        work = sum(trial_input_bytes(name, root, t) for t in trials)
        on_done = None
        if progress is not None and trials:
            progress(0, len(trials))
            on_done = lambda done, total, i: progress(done, total, trials[i])  # noqa: E731
        timed = pmap(timed_task(_run_trial, name), [(name, root, vehicle, params, t) for t in trials],
                     work_bytes=work, on_done=on_done)
        return merge_results(name, [task_result(r, name, t) for r, t in zip(timed, trials, strict=True)])
    return call_stage(name, root, vehicle, params, **kwargs)


def _size(path: Path) -> int:
    """Bytes of a file, or of every file under a directory (a rosbag2 directory, a trial's streams); 0 if gone."""
    try:
        if path.is_dir():
            return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
        return path.stat().st_size
    except OSError:
        return 0


def trial_input_bytes(name: str, root: Path, trial: str) -> int:
    """The bytes a per-trial stage reads for ``trial`` (what decides whether a process pool pays)."""
    from pipeline import layout

    root = Path(root)
    signals = layout.signals_dir(root, trial)
    if name == "sync":
        return _size(signals)
    if name == "differentiate":
        return _size(layout.synced_path(root, trial)) + _size(signals)
    if name == "derive":
        return _size(layout.kinematics_path(root, trial))
    return 0


def require_stages(names: list[str] | tuple[str, ...]) -> None:
    """Raise one MissingStageError naming every stage of ``names`` that cannot be loaded."""
    missing = []
    for name in names:
        try:
            load_stage(name)
        except MissingStageError as err:
            missing.append(f"{name} ({err.reason})")
    if missing:
        raise MissingStageError("cannot run the DAG, missing stage(s): " + "; ".join(missing))


def run_stages(root: Path, vehicle: Vehicle, params: Params, stages: list[str] | tuple[str, ...] = STAGE_ORDER,
               *, logs: list[Path] | None = None,
               progress_factory: Callable[[str], Callable[..., Any] | None] | None = None,
               on_stage: Callable[[str, StageResult | None, float], None] | None = None) -> list[StageResult]:
    """Run ``stages`` in DAG order without DVC. Checks that every stage exists before running any.

    ``progress_factory(stage)`` gives the progress callback for a stage (or None); ``on_stage(stage, result,
    seconds)`` is called before (result None) and after each stage. A PipelineError stops the run; so does an
    ingest that leaves no trial at all (every log quarantined): the list is then shorter than ``stages``.
    The run root's lock is held throughout (:mod:`pipeline.rootlock`): RunRootBusy if another command has it.
    """
    with run_root_lock(root):
        return _run_stages(root, vehicle, params, stages, logs=logs, progress_factory=progress_factory,
                           on_stage=on_stage)


def _run_stages(root: Path, vehicle: Vehicle, params: Params, stages: list[str] | tuple[str, ...], *,
                logs: list[Path] | None,
                progress_factory: Callable[[str], Callable[..., Any] | None] | None,
                on_stage: Callable[[str, StageResult | None, float], None] | None) -> list[StageResult]:
    import time

    from pipeline.parallel import record_task, release_workers

    ordered = [s for s in STAGE_ORDER if s in set(stages)]
    require_stages(ordered)
    last_fan_out = max((i for i, s in enumerate(ordered) if s == "ingest" or s in PER_TRIAL), default=-1)
    results = []
    for i, name in enumerate(ordered):
        if on_stage is not None:
            on_stage(name, None, 0.0)
        start, started, cpu0 = time.perf_counter(), time.time(), time.process_time()
        progress = progress_factory(name) if progress_factory is not None else None
        try:
            result = run_stage(name, root, vehicle, params, logs=logs, progress=progress)
        finally:
            close = getattr(progress, "close", None)
            if callable(close):
                close()
            if i == last_fan_out:  # the pool's workers, kept from stage to stage, are not needed any more
                release_workers()
        # the stage as a whole, after the one before it (its tasks are recorded under its name)
        record_task("run", name, start=started, wall_s=time.perf_counter() - start,
                    cpu_s=time.process_time() - cpu0, deps=[ordered[i - 1]] if i else [])
        results.append(result)
        if on_stage is not None:
            on_stage(name, result, time.perf_counter() - start)
        if name == "ingest" and name != ordered[-1] and not discover_trials(root):
            log.warning("every log was quarantined and no trial is left: stopping after ingest")
            break
    return results


def trial_output(name: str, root: Path, trial: str) -> Path:
    """The file a per-trial stage writes for ``trial``."""
    from pipeline import layout

    return {"sync": layout.synced_path, "differentiate": layout.kinematics_path,
            "derive": layout.derived_path}[name](Path(root), trial)
