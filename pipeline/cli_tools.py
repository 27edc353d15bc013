"""The ``auvid models`` and ``auvid export`` commands: part of the CLI (they print and choose exit codes), kept
apart from :mod:`pipeline.cli` to keep that module short. Exit codes as in :mod:`pipeline.cli`."""

from __future__ import annotations

import argparse
import json
import sys
import time

from pipeline.cli import EXIT_FAILED, EXIT_OK, UsageError, _check_paths, _progress_factory


def cmd_export(args: argparse.Namespace) -> int:
    from pipeline.export import export_trials, trials_available

    _check_paths([args.root], "run directory")
    have = trials_available(args.root)
    if not have:
        raise UsageError(f"nothing to export: no synced trial under {args.root / 'data' / 'synced'} (run `auvid "
                         "run` or `auvid sync` first)")
    unknown = [t for t in args.trial or [] if t not in have]
    if unknown:
        raise UsageError(f"no synced table for trial(s) {unknown}; available: {have}")
    start = time.perf_counter()
    results = export_trials(args.root, args.trial, args.out, progress_factory=_progress_factory(args))
    for r in results if not args.quiet else []:
        print(f"[export] {r.path}: {sum(r.messages.values())} message(s) on {len(r.messages)} channel(s)")
        for reason in r.skipped:
            print(f"  not exported: {reason}", file=sys.stderr)
    print(f"auvid export: done (exit 0): {len(results)} trial(s) in {time.perf_counter() - start:.1f} s -> "
          f"{results[0].path.parent}", flush=True)
    return EXIT_OK


def cmd_models(args: argparse.Namespace) -> int:
    from pipeline import registry

    root = args.root.resolve()
    if not registry.registry_path(root).is_file():
        raise UsageError(f"no model registry at {registry.registry_path(root)} (give the retraining home with "
                         "--root; `auvid retrain` creates it)")
    action = args.models_command
    try:
        if action == "list":
            data = registry.load(root)
            print(json.dumps(registry.rows(data), indent=2) if args.json else registry.format_table(data))
        elif action == "show":
            info = registry.describe_version(registry.load(root), args.version, root)
            print(json.dumps(info, indent=2, sort_keys=True) if args.json else registry.format_version(info, root))
        else:
            before = registry.load(root).get("current")
            data = registry.promote(root, args.version) if action == "promote" else registry.rollback(root)
            now = data["current"]
            print(f"models {action}: {now} is current" + (f" (was {before})" if before != now else
                                                          " (it already was; nothing changed)"))
    except registry.UnknownVersion as err:
        raise UsageError(str(err)) from None
    except registry.LockBusy:
        print(f"auvid: models {action}: a retrain (or another promotion) holds {root / registry.LOCK_FILE}; "
              "nothing changed, try again when it ends", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK
