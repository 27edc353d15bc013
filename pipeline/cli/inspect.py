"""``auvid inspect``: a log's topics (or a text file's columns), types, rates, gaps and time-stamp warnings."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from pipeline.cli.common import EXIT_OK, UsageError, check_paths, user_definitions
from pipeline.errors import IngestError, PipelineError


def cmd_inspect(args: argparse.Namespace) -> int:
    try:
        from pipeline.io.inspect import format_fields, format_inspect, inspect_log, topic_fields
    except ImportError as err:
        raise PipelineError(f"`auvid inspect` is not available in this build: {err}") from None
    check_paths([args.log], "log")
    _check_directory(args.log)
    definitions, csv_options = user_definitions(args)
    if args.fields is not None:
        try:
            fields = topic_fields(args.log, args.fields, definitions=definitions, csv_options=csv_options)
        except IngestError as err:
            if err.topic == args.fields and not _has_topic(args.log, args.fields, definitions):
                raise UsageError(f"--fields: {err}") from None  # a mistyped topic, not a damaged log
            raise
        print(json.dumps(fields, indent=2) if args.json else format_fields(fields))
        return EXIT_OK
    info = inspect_log(args.log, definitions=definitions, csv_options=csv_options, time_rates=_time_rates(args))
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True, default=str))
    else:
        print(format_inspect(info))
    return EXIT_OK


def _time_rates(args: argparse.Namespace) -> dict[str, float]:
    """Per text file pattern, the vehicle config's ``time: {rate_hz}`` (for this log's trial, overrides applied):
    inspect rebuilds those files' times as ingest does."""
    if getattr(args, "vehicle", None) is None:
        return {}
    from pipeline.config import load_vehicle
    from pipeline.ingest import trial_id

    vehicle = load_vehicle(args.vehicle).for_trial(trial_id(args.log))
    return {s.file: s.time.rate_hz for s in vehicle.streams.values() if s.file is not None and s.time is not None}


def _check_directory(path: Path) -> None:
    """A directory that is no ROS 2 bag and holds no text files (empty, or several logs) names nothing to inspect:
    a usage error (exit 2), as a missing path is; a damaged log stays a failure (exit 3)."""
    if not path.is_dir():
        return
    from pipeline.io.detect import sniff

    if not any(path.iterdir()):
        raise UsageError(f"nothing to inspect: {path} is an empty directory")
    try:
        sniff(path)
    except IngestError as err:
        raise UsageError(f"nothing to inspect: {err} (give one log: a file, a ROS 2 bag directory or a directory "
                         "of text files)") from None


def _has_topic(path: Path, topic: str, definitions: Any) -> bool:
    """Whether the log lists ``topic`` (asked only after topic_fields failed on it)."""
    from pipeline.io.inspect import open_any

    try:
        with open_any(path, definitions) as reader:
            infos = reader.catalog() if hasattr(reader, "catalog") else reader.topics()
    except PipelineError:
        return True  # the log itself cannot be listed: a failure, not a usage mistake
    return topic in infos
