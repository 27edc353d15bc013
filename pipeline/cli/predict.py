"""``auvid predict``: the loaded models' accelerations on a log (run through ingest..derive with the run's configs
in a temporary directory) or on a Parquet table (:mod:`pipeline.predict`, :mod:`pipeline.api`)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from pipeline.cli.common import EXIT_OK, UsageError, check_paths, on_stage, progress_factory


def cmd_predict(args: argparse.Namespace) -> int:
    from pipeline.api import LoadError, load
    from pipeline.config import load_params
    from pipeline.predict import OUTPUT_SUFFIXES, PredictError, derive_log, predict_frame, write_predictions

    check_paths([args.input], "input")
    check_paths([args.root], "run directory or retraining home")
    out = args.out or Path(f"{args.input.name.split('.')[0]}.predictions.parquet")
    if out.suffix.lower() not in OUTPUT_SUFFIXES:
        raise UsageError(f"--out {out}: unknown format {out.suffix!r}; use one of {list(OUTPUT_SUFFIXES)}")
    start = time.perf_counter()
    try:
        models = load(args.root, version=args.version, alias=args.alias, vehicle=args.vehicle, params=args.params)
        if args.model:
            unknown = [m for m in args.model if m not in models]
            if unknown:
                raise UsageError(f"--model {unknown[0]}: no such model in {models.source}; available: {sorted(models)}")
            models_used = {m: models[m] for m in args.model}
        else:
            models_used = dict(models)
        if args.input.is_file() and args.input.suffix.lower() == ".parquet":
            import pyarrow.parquet as pq

            try:
                frame = pq.read_table(args.input).to_pandas()
            except Exception as err:  # noqa: BLE001 - an unreadable table is the user's file, named
                raise UsageError(f"{args.input}: not a readable Parquet table ({type(err).__name__}: {err})") from None
        else:
            vehicle = next(iter(models_used.values())).vehicle
            if vehicle is None:
                raise UsageError(f"predicting on a log needs the vehicle config: none beside {models.source} "
                                 "(give --vehicle)")
            params_path = args.params or (models.source / "params.yaml")
            params = load_params(params_path if Path(params_path).is_file() else None)
            frame = derive_log(args.input, vehicle, params, progress_factory(args), on_stage(args))
        table = predict_frame(models_used, frame, args.input)
    except (LoadError, PredictError) as err:
        raise UsageError(str(err)) from None
    write_predictions(table, out, {"command": "auvid predict", "input": str(args.input),
                                   "models": sorted(models_used), "source": str(models.source),
                                   "version": models.version})
    if not args.quiet:
        for name, m in models_used.items():
            print(f"[predict] {name}: {', '.join(m.outputs)}" + (f" with its {m.interval_kind}" if m.has_interval
                                                                  else ""))
    print(f"auvid predict: done (exit 0): {len(models_used)} model(s) on {table.num_rows} row(s) in "
          f"{time.perf_counter() - start:.1f} s -> {out}", flush=True)
    return EXIT_OK
