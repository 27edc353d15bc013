"""What every ``auvid`` command shares: exit codes, the usage error, progress bars and per-stage lines, the
paths and message definitions a command line names. See :mod:`pipeline.cli` for what each exit code means."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pipeline.errors import ConfigError

EXIT_OK, EXIT_QUARANTINED, EXIT_USAGE, EXIT_FAILED = 0, 1, 2, 3
EXIT_INTERRUPTED, EXIT_PIPE = 130, 141  # 128 + SIGINT, 128 + SIGPIPE, as a shell reports them


class UsageError(Exception):
    """A command line that cannot be run: a path that does not exist, nothing to process (exit 2)."""


class Progress:
    """A stage progress callback drawn as a tqdm bar; silent when stdout is not a terminal.

    Called as ``progress(done, total=None, desc=None)`` (absolute position), ``progress("label")`` (one more
    unit done) or ``progress.update(n)``.
    """

    def __init__(self, label: str, enabled: bool | None = None) -> None:
        self.label = label
        self.enabled = sys.stdout.isatty() if enabled is None else enabled
        self._bar: Any = None
        self.done = 0
        self.total: int | None = None

    def _ensure(self) -> Any:
        if self._bar is None and self.enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, desc=self.label, unit="", leave=False, file=sys.stdout)
        return self._bar

    def __call__(self, done: int | float | str, total: int | float | None = None, desc: str | None = None) -> None:
        if isinstance(done, str):
            done, desc = self.done + 1, done
        self.done = int(done)
        if total is not None:
            self.total = int(total)
        bar = self._ensure()
        if bar is not None:
            if total is not None and bar.total != self.total:
                bar.total = self.total
            if desc:
                bar.set_postfix_str(str(desc)[-40:], refresh=False)
            bar.n = self.done
            bar.refresh()

    def update(self, n: int = 1) -> None:
        self(self.done + n, self.total)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def progress_factory(args: argparse.Namespace) -> Callable[[str], Progress]:
    """One :class:`Progress` per stage, drawn only on a terminal and not with ``-q``."""
    enabled = sys.stdout.isatty() and not getattr(args, "quiet", False)
    return lambda stage: Progress(stage, enabled)


def salvaged(result: Any) -> list[str]:
    """The damaged logs a stage read in part (its summary's ``salvaged``)."""
    summary = result.summary if isinstance(getattr(result, "summary", None), dict) else {}
    return [str(t) for t in summary.get("salvaged", [])]


def print_stage(stage: str, result: Any, seconds: float) -> None:
    """The per-stage lines (not with -q): one when a stage starts, one when it ends, then each quarantine
    reason once on stderr."""
    if result is None:
        print(f"[{stage}] ...", flush=True)
        return
    if result.summary.get("skipped"):
        print(f"[{stage}] skipped: {result.summary['skipped']}", flush=True)
        return
    line = f"[{stage}] {len(result.outputs)} output(s) in {seconds:.1f} s"
    if result.quarantined:
        line += f", {len(result.quarantined)} quarantined"
    if salvaged(result):
        line += f", {len(salvaged(result))} salvaged (damaged, partly read: see the ingest report)"
    print(line, flush=True)
    for entry in result.quarantined:
        print(f"  quarantined {entry.get('file') or entry.get('model')}: {entry.get('reason')}", file=sys.stderr)


def on_stage(args: argparse.Namespace) -> Callable[[str, Any, float], None] | None:
    """The per-stage line printer, or None with ``-q``."""
    return None if getattr(args, "quiet", False) else print_stage


def check_paths(paths: list[Path], what: str) -> None:
    """A :class:`UsageError` naming every path given that does not exist."""
    missing = [str(p) for p in paths if not Path(p).exists()]
    if missing:
        raise UsageError(f"{what} not found: {', '.join(missing)}")


def user_definitions(args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    """The user's message definitions (--msgs, then the vehicle config's) and the config's CSV options."""
    from pipeline.io.msgdefs import load_user_types

    dirs = [Path(d) for d in getattr(args, "definitions", [])]
    csv_options: dict[str, Any] = {}
    vehicle_path = getattr(args, "vehicle", None)
    if vehicle_path is not None:
        from pipeline.config import load_vehicle
        from pipeline.ingest import user_types

        vehicle = load_vehicle(vehicle_path)
        own = user_types(vehicle)
        dirs += list(own.dirs) if own is not None else []
        csv_options = {s.file: s.csv for s in vehicle.streams.values() if s.file is not None and s.csv is not None}
    for d in dirs:
        if not d.is_dir():
            raise ConfigError(f"message definition directory {str(d)!r} does not exist")
    return (load_user_types(dirs) if dirs else None), csv_options
