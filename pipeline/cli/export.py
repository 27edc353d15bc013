"""``auvid export``: one MCAP per trial for Foxglove and PlotJuggler (:mod:`pipeline.export`)."""

from __future__ import annotations

import argparse
import sys
import time

from pipeline.cli.common import EXIT_OK, UsageError, check_paths, progress_factory


def cmd_export(args: argparse.Namespace) -> int:
    from pipeline.config import load_params
    from pipeline.export import export_trials, named_models, trials_available

    check_paths([args.root], "run directory")
    if args.fossen is not None:
        return _export_fossen(args)
    have = trials_available(args.root)
    if not have:
        raise UsageError(f"nothing to export: no synced trial under {args.root / 'data' / 'synced'} (run `auvid "
                         "run` or `auvid sync` first)")
    unknown = [t for t in args.trial or [] if t not in have]
    if unknown:
        raise UsageError(f"no synced table for trial(s) {unknown}; available: {have}")
    # only the models the run's params name are loaded (as the simulate stage does)
    params_path = args.params or (args.root / "params.yaml" if (args.root / "params.yaml").is_file() else None)
    models = named_models(load_params(params_path))
    start = time.perf_counter()
    results = export_trials(args.root, args.trial, args.out, progress_factory=progress_factory(args), models=models)
    for r in results if not args.quiet else []:
        print(f"[export] {r.path}: {sum(r.messages.values())} message(s) on {len(r.messages)} channel(s)")
        for reason in r.skipped:
            print(f"  not exported: {reason}", file=sys.stderr)
    print(f"auvid export: done (exit 0): {len(results)} trial(s) in {time.perf_counter() - start:.1f} s -> "
          f"{results[0].path.parent}", flush=True)
    return EXIT_OK


def _export_fossen(args: argparse.Namespace) -> int:
    from pipeline.api import LoadError, load
    from pipeline.fossen import FossenError, write_fossen, write_uuv

    try:
        models = load(args.root, params=args.params)
        if args.fossen not in models:
            raise UsageError(f"--fossen {args.fossen}: no such model in {args.root}; available: {sorted(models)}")
        model = models[args.fossen]
        out = args.out or args.root / "exports"
        paths = [write_fossen(model, out / f"fossen_{model.name}.yaml"),
                 write_uuv(model, out / f"uuv_{model.name}.xml")]
    except (LoadError, FossenError) as err:
        raise UsageError(str(err)) from None
    print(f"auvid export: done (exit 0): model {model.name} -> {', '.join(str(p) for p in paths)}", flush=True)
    return EXIT_OK
