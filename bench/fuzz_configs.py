"""The long property-based config campaign (issue 36, item 3): thousands of generated params and vehicle configs.

    python bench/fuzz_configs.py                          # 1,000 params + 1,000 vehicle configs, seed 0
    python bench/fuzz_configs.py --examples 5000 --seed 7 --json /tmp/configs.json

The edits are those of the in-suite campaign (``tests/config/strategies.py``), drawn here from a seeded
``random.Random`` per config (uniform; Hypothesis, in the suite, favours some values): a real config with one to
three edits (numbers at and beyond their bounds, wrong types, empty and huge lists, special files, dropped and
unknown keys). Each config is written to a YAML file and loaded (``load_params`` / ``load_vehicle`` and the
cross-checks); outcomes: ``loaded``; ``refused`` (a ConfigError naming the file and a key); ``unnamed`` (a
ConfigError without both); ``uncaught`` (any other exception); ``slow`` (over ``--time-limit`` seconds). A case
that is neither loaded nor refused is printed with its edits.

    nice python bench/fuzz_configs.py --run --examples 300 --seed 3711   # and every config that loads is run

``--run``: each config that loads runs ``auvid run`` on three 40-s simulated trials (two MCAP, one a directory of CSV
exports with a tank table, so the ``csv:`` options are read), written once, in a subprocess
under CPU, address-space and wall limits (``tests/config/runs.py``: to ``derive``; to ``report`` with cheap
untouched keys where a params edit touches the model sections). Run outcomes: ``refused`` (exit 2 naming file and
key), ``ran-ok``, ``quarantine`` (exit 1), ``stage-failed`` (exit 3, one line); and the failures ``unnamed``,
``traceback``, ``hang``, ``memory``, ``nonsense`` (exit 0 with non-finite model columns, an empty store without a
warning, or NaN in an output JSON), each printed with its edits.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT)]

OUTCOMES = ["loaded", "refused", "unnamed", "uncaught", "slow"]


def campaign(kind: str, examples: int, seed: int, time_limit_s: float, tmp: Path,
             raw: list[Path] | None = None) -> list[dict[str, Any]]:
    """``examples`` generated configs of ``kind`` (params / vehicle), each loaded; their outcomes. Config ``i`` is
    drawn from ``random.Random(f"{seed}:{kind}:{i}")``: uniform over key shapes and values, replayable alone.
    With ``raw`` (the run campaign's logs), each config that loads is run too (``run`` and ``run_detail``)."""
    import random

    from tests.config.strategies import PARAMS, VEHICLE, outcome, random_edit, write

    records: list[dict[str, Any]] = []
    for i in range(examples):
        doc, what = random_edit(PARAMS if kind == "params" else VEHICLE, random.Random(f"{seed}:{kind}:{i}"))
        path = write(tmp / f"{kind}.yaml", doc)
        result, detail = outcome(kind, path, time_limit_s=time_limit_s)
        record = {"kind": kind, "case": i, "edits": what, "outcome": result, "detail": detail}
        if raw is not None and result == "loaded":
            from tests.config.runs import run_config

            record["run"], record["run_detail"], record["run_s"] = run_config(kind, doc, what, raw, tmp / "work")
            print(f"  {kind} {i}: {record['run']} in {record['run_s']:.1f} s {record['run_detail'][:100]}",
                  file=sys.stderr, flush=True)
        records.append(record)
    return records


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--examples", type=int, default=1000, help="configs per kind (params, vehicle)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--time-limit", type=float, default=5.0, help="seconds a load may take")
    ap.add_argument("--json", type=Path, help="write every config's edits and outcome here")
    ap.add_argument("--run", action="store_true", help="run `auvid run` on every config that loads")
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)  # the loaders' warnings are not the result
    t0 = time.monotonic()
    records: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="fuzz-configs-") as tmp:
        raw = None
        if args.run:
            from tests.config.runs import raw_logs

            raw = raw_logs(Path(tmp) / "raw")
        for kind in ("params", "vehicle"):
            records += campaign(kind, args.examples, args.seed, args.time_limit, Path(tmp), raw)
    elapsed = time.monotonic() - t0
    print(f"seed {args.seed}, {len(records)} configs, {elapsed:.0f} s, limit {args.time_limit:g} s a load\n")
    _print_counts(records, "outcome", OUTCOMES)
    bad = [r for r in records if r["outcome"] not in ("loaded", "refused")]
    for r in bad:
        print(f"\n{r['kind']} {r['case']} {r['outcome']}: {r['edits']}\n    {r['detail']}")
    if args.run:
        bad += _run_table([r for r in records if "run" in r])
    if args.json:
        args.json.write_text(json.dumps(records, indent=1, default=str))
    return 1 if bad else 0


def _print_counts(records: list[dict[str, Any]], field: str, outcomes: tuple[str, ...] | list[str]) -> None:
    """A markdown table: per kind of config (and all), how many records have each ``field`` outcome."""
    print("| kind | " + " | ".join(outcomes) + " |")
    print("| --- | " + " | ".join("---:" for _ in outcomes) + " |")
    for kind in ("params", "vehicle", "all"):
        row = Counter(r[field] for r in records if kind in ("all", r["kind"]))
        print(f"| {kind} | " + " | ".join(str(row[o]) for o in outcomes) + " |")


def _run_table(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Print the run campaign's table and its failures (returned); its stage failures are printed too."""
    from tests.config.runs import GOOD, RUN_OUTCOMES

    seconds = sum(r["run_s"] for r in runs)
    print(f"\nruns of the configs that loaded: {len(runs)}, {seconds:.0f} s in all\n")
    _print_counts(runs, "run", RUN_OUTCOMES)
    for r in runs:
        if r["run"] not in ("ran-ok", "refused"):
            print(f"\n{r['kind']} {r['case']} run {r['run']}: {r['edits']}\n    {r['run_detail']}")
    return [r for r in runs if r["run"] not in GOOD]


if __name__ == "__main__":
    sys.exit(main())
