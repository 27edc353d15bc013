"""``auvid inspect``: a log's topics (or a text file's columns), types, rates, gaps and time-stamp warnings."""

from __future__ import annotations

import argparse
import json

from pipeline.cli.common import EXIT_OK, check_paths, user_definitions
from pipeline.errors import PipelineError


def cmd_inspect(args: argparse.Namespace) -> int:
    try:
        from pipeline.io.inspect import format_fields, format_inspect, inspect_log, topic_fields
    except ImportError as err:
        raise PipelineError(f"`auvid inspect` is not available in this build: {err}") from None
    check_paths([args.log], "log")
    definitions, csv_options = user_definitions(args)
    if args.fields is not None:
        fields = topic_fields(args.log, args.fields, definitions=definitions, csv_options=csv_options)
        print(json.dumps(fields, indent=2) if args.json else format_fields(fields))
        return EXIT_OK
    info = inspect_log(args.log, definitions=definitions, csv_options=csv_options)
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True, default=str))
    else:
        print(format_inspect(info))
    return EXIT_OK
