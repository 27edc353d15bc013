"""``auvid retrain``: ingest new logs from an inbox, retrain, promote only if better (:mod:`pipeline.retrain`)."""

from __future__ import annotations

import argparse

from pipeline.cli.common import EXIT_OK, EXIT_QUARANTINED, UsageError, on_stage, progress_factory


def cmd_retrain(args: argparse.Namespace) -> int:
    from pipeline.retrain import RetrainOptions, retrain

    root = args.root.resolve()
    if not args.inbox.is_dir():
        raise UsageError(f"inbox {args.inbox} is not a directory")
    options = RetrainOptions(root=root, inbox=args.inbox.resolve(),
                             vehicle_path=(args.vehicle or root / "vehicle.yaml").resolve(),
                             params_path=args.params.resolve() if args.params else None,
                             progress_factory=progress_factory(args), on_stage=on_stage(args))
    outcome = retrain(options)
    print(f"retrain: {outcome.message}")
    return EXIT_QUARANTINED if outcome.quarantined else EXIT_OK
