"""What every stage shell shares: arguments, config loading, the result it reports, exit codes.

A stage module defines ``run(root, vehicle, params, **kw) -> StageResult`` (reads inputs, calls the
library, writes outputs) and ``main(argv) = stage_main(NAME, run, argv)``. Exit codes: 0 done, 1 done
with quarantined inputs, 2 usage or config error.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.config import Params, Vehicle, load_params, load_vehicle
from pipeline.errors import ConfigError, PipelineError

log = logging.getLogger(__name__)

EXIT_OK, EXIT_QUARANTINED, EXIT_USAGE = 0, 1, 2


@dataclass
class StageResult:
    stage: str
    outputs: list[Path] = field(default_factory=list)
    quarantined: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        return EXIT_QUARANTINED if self.quarantined else EXIT_OK


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--root", type=Path, default=Path("."), help="run directory holding data/ (default: .)")
    parser.add_argument("--vehicle", type=Path, default=Path("vehicle.yaml"), help="vehicle config YAML")
    parser.add_argument("--params", type=Path, default=None,
                        help="params YAML (default: params.yaml in the run directory if present)")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def load_configs(root: Path, vehicle_path: Path, params_path: Path | None) -> tuple[Vehicle, Params]:
    if params_path is None and (root / "params.yaml").exists():
        params_path = root / "params.yaml"
    return load_vehicle(vehicle_path), load_params(params_path)


def stage_main(name: str, run: Callable[..., StageResult], argv: list[str] | None = None,
               extra: Callable[[argparse.ArgumentParser], None] | None = None) -> int:
    """Parse arguments, load configs, run the stage, print a one-line summary, return the exit code."""
    parser = argparse.ArgumentParser(prog=f"python -m stages.{name}", description=(run.__doc__ or "").strip())
    add_common_arguments(parser)
    if extra is not None:
        extra(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    kwargs = {k: v for k, v in vars(args).items() if k not in {"root", "vehicle", "params", "verbose"}}
    try:
        vehicle, params = load_configs(args.root, args.vehicle, args.params)
        result = run(args.root, vehicle, params, **kwargs)
    except ConfigError as err:
        print(f"config error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except PipelineError as err:
        print(f"{name} failed: {err}", file=sys.stderr)
        return EXIT_USAGE
    print(f"{name}: {len(result.outputs)} output(s), {len(result.quarantined)} quarantined")
    for entry in result.quarantined:
        print(f"  quarantined {entry.get('file')}: {entry.get('reason')}", file=sys.stderr)
    return result.exit_code
