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


def campaign(kind: str, examples: int, seed: int, time_limit_s: float, tmp: Path) -> list[dict[str, Any]]:
    """``examples`` generated configs of ``kind`` (params / vehicle), each loaded; their outcomes. Config ``i`` is
    drawn from ``random.Random(f"{seed}:{kind}:{i}")``: uniform over key shapes and values, replayable alone."""
    import random

    from tests.config.strategies import PARAMS, VEHICLE, outcome, random_edit, write

    records: list[dict[str, Any]] = []
    for i in range(examples):
        doc, what = random_edit(PARAMS if kind == "params" else VEHICLE, random.Random(f"{seed}:{kind}:{i}"))
        path = write(tmp / f"{kind}.yaml", doc)
        result, detail = outcome(kind, path, time_limit_s=time_limit_s)
        records.append({"kind": kind, "case": i, "edits": what, "outcome": result, "detail": detail})
    return records


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--examples", type=int, default=1000, help="configs per kind (params, vehicle)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--time-limit", type=float, default=5.0, help="seconds a load may take")
    ap.add_argument("--json", type=Path, help="write every config's edits and outcome here")
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)  # the loaders' warnings are not the result
    t0 = time.monotonic()
    records: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="fuzz-configs-") as tmp:
        for kind in ("params", "vehicle"):
            records += campaign(kind, args.examples, args.seed, args.time_limit, Path(tmp))
    elapsed = time.monotonic() - t0
    print(f"seed {args.seed}, {len(records)} configs, {elapsed:.0f} s, limit {args.time_limit:g} s a load\n")
    print("| kind | " + " | ".join(OUTCOMES) + " |")
    print("| --- | " + " | ".join("---:" for _ in OUTCOMES) + " |")
    for kind in ("params", "vehicle", "all"):
        row = Counter(r["outcome"] for r in records if kind in ("all", r["kind"]))
        print(f"| {kind} | " + " | ".join(str(row[o]) for o in OUTCOMES) + " |")
    bad = [r for r in records if r["outcome"] not in ("loaded", "refused")]
    for r in bad:
        print(f"\n{r['kind']} {r['case']} {r['outcome']}: {r['edits']}\n    {r['detail']}")
    if args.json:
        args.json.write_text(json.dumps(records, indent=1, default=str))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
