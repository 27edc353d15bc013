"""The embedded example: a DAGON-like vehicle simulated by ``pipeline.sim``, laid out as a run directory.

``prepare(out)`` writes ``out/data/raw/<trial>.mcap`` (the simulated trial logs), ``out/vehicle.yaml`` (the
vehicle config the simulator wrote for its logs) and ``out/params.yaml`` (what the example changes from the
defaults: small, fast settings that still exercise every stage), and returns where they are. Both configs start
with the ``# yaml-language-server: $schema=./<kind>.schema.json`` line that ``auvid init`` writes, naming a copy
of the package's JSON Schema beside them (``out/vehicle.schema.json``, ``out/params.schema.json``), so that an
editor validates and completes them wherever the run directory goes. ``auvid demo`` then runs the DAG on it;
``dvc.yaml``'s ``example`` stage calls the same function for the repository's own run directory.
"""

from __future__ import annotations

import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from pipeline import layout
from pipeline.config import Params, parse
from pipeline.errors import PipelineError

log = logging.getLogger(__name__)

DEFAULT_DURATION_S = 150.0
LOG_SUFFIXES = (".mcap", ".bag", ".db3")
MODELINE_PREFIX = "# yaml-language-server:"


@dataclass(frozen=True)
class DemoSetup:
    root: Path
    logs: list[Path]
    vehicle_path: Path
    params_path: Path
    trials: list[str]


def demo_params(trials: list[str]) -> dict[str, Any]:
    """What the example changes from the code's defaults (every key has one): a 10-Hz grid, the last trial held
    out, and the studies and free runs sized to finish in minutes on two cores. Every stage and every model runs.
    The repository's ``params.yaml`` holds the same keys (tests/cli/test_dvc.py checks it)."""
    test = [trials[-1]] if len(trials) >= 2 else []
    params = {
        "sync": {"rate_hz": 10.0},
        "features": {"test_trials": test},
        "coupled": {"folds": 3},
        "decoupled": {"folds": 3, "gp_max_samples": 200, "max_samples": 600, "curve_points": 3},
        "simulate": {"outage_windows_s": [10.0, 30.0], "band_samples": 8},
    }
    # Keys another version of the params model does not know are left out (the model evolves per stage).
    for section, values in params.items():
        known = Params.model_fields[section].annotation.model_fields  # type: ignore[union-attr]
        params[section] = {k: v for k, v in values.items() if k in known}
    parse(Params, params, "demo params")  # fail here, not three stages later
    return params


def _find_logs(directory: Path) -> list[Path]:
    found: list[Path] = []
    for path in sorted(directory.rglob("*")):
        if any(parent in found for parent in path.parents):
            continue
        if path.is_file() and path.suffix in LOG_SUFFIXES and not (path.parent / "metadata.yaml").exists():
            found.append(path)
        elif path.is_dir() and (path / "metadata.yaml").exists():
            found.append(path)
    return found


def _add_modeline(path: Path, kind: str) -> None:
    """Put the schema line first in a config file (replacing one that names another path), naming the schema
    copied beside it: the line stays valid when the run directory moves."""
    from pipeline.config.schemas import copy_schema, schema_modeline

    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    if lines and lines[0].startswith(MODELINE_PREFIX):
        lines = lines[1:]
    copy_schema(path.parent, kind)
    path.write_text(schema_modeline(kind, beside=True) + "\n" + "".join(lines), encoding="utf-8")


def _generate_logs(target: Path, duration_s: float, seed: int) -> Any:
    try:
        from pipeline.sim import example
    except ImportError as err:
        raise PipelineError(f"the example simulator is not available (pipeline.sim.example): {err}") from None
    return example(target, fmt="mcap", duration_s=duration_s, seed=seed)


def prepare(out: str | Path, *, duration_s: float | None = None, seed: int = 0) -> DemoSetup:
    """Simulate the example trials and lay out ``out`` as a run directory (see the module docstring)."""
    from pipeline.ingest import trial_id

    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    gen = out / ".example"
    if gen.exists():
        shutil.rmtree(gen)
    written = _generate_logs(gen, duration_s or DEFAULT_DURATION_S, seed)
    vehicles = [Path(written.vehicle)] if getattr(written, "vehicle", None) else sorted(gen.rglob("vehicle.yaml"))
    if not vehicles:
        raise PipelineError("the example simulator wrote no vehicle.yaml", file=gen)
    logs = [Path(p) for p in getattr(written, "trials", [])] or _find_logs(gen)
    if not logs:
        raise PipelineError("the example simulator wrote no trial logs", file=gen)
    raw = out / layout.RAW
    if raw.exists():
        shutil.rmtree(raw)
    raw.mkdir(parents=True)
    moved = []
    for path in logs:
        target = raw / path.name
        os.replace(path, target)
        moved.append(target)
    # The vehicle config and anything it refers to (thrust tables) stay together, next to params.yaml.
    vehicle_src = vehicles[0]
    for item in vehicle_src.parent.iterdir():
        if item.is_file() and item.suffix not in LOG_SUFFIXES:
            shutil.copy2(item, out / item.name)
    vehicle_path = out / vehicle_src.name
    if vehicle_path.name != "vehicle.yaml":
        os.replace(vehicle_path, out / "vehicle.yaml")
        vehicle_path = out / "vehicle.yaml"
    shutil.rmtree(gen, ignore_errors=True)
    trials = sorted(trial_id(p) for p in moved)
    _add_modeline(vehicle_path, "vehicle")
    params_path = out / "params.yaml"
    params_path.write_text("# auvid demo params (auvid demo writes this file; see pipeline/config/params.py)\n"
                           + yaml.safe_dump(demo_params(trials), sort_keys=False))
    _add_modeline(params_path, "params")
    log.info("demo: %d trial(s) %s in %s", len(trials), trials, out)
    return DemoSetup(root=out, logs=sorted(moved), vehicle_path=vehicle_path, params_path=params_path,
                     trials=trials)
