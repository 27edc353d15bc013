"""``auvid models``: the retraining registry: list versions, show one, promote, roll back (:mod:`pipeline.registry`)."""

from __future__ import annotations

import argparse
import json
import sys

from pipeline.cli.common import EXIT_FAILED, EXIT_OK, UsageError


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
        elif action == "promote" and args.model is not None:
            data = registry.promote_model(root, args.version, args.model, args.output, args.alias)
            table = data["aliases"][args.alias]
            print(f"models promote: {args.alias} = " + ", ".join(f"{o} <- {e['model']} of {e['version']}"
                                                                 for o, e in sorted(table.items()))
                  + f" (current stays {data.get('current')})")
        else:
            if getattr(args, "output", None):
                raise UsageError("--output needs --model (a whole version has no per-output promotion)")
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
