"""The long property-based config campaign (issue 36, item 3): thousands of generated params and vehicle configs.

    python bench/fuzz_configs.py                          # 1,000 params + 1,000 vehicle configs, seed 0
    python bench/fuzz_configs.py --examples 5000 --seed 7 --json /tmp/configs.json

The strategies are those of the in-suite campaign (``tests/config/strategies.py``): a real config with one to
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
    """``examples`` generated configs of ``kind`` (params / vehicle), each loaded; their outcomes."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import seed as hseed

    from tests.config.strategies import PARAMS, VEHICLE, edited, outcome, write

    records: list[dict[str, Any]] = []

    @hseed(seed)
    @settings(max_examples=examples, database=None, deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(edited(PARAMS if kind == "params" else VEHICLE))
    def run(case: tuple[dict[str, Any], list[str]]) -> None:
        doc, what = case
        path = write(tmp / f"{kind}.yaml", doc)
        result, detail = outcome(kind, path, time_limit_s=time_limit_s)
        records.append({"kind": kind, "edits": what, "outcome": result, "detail": detail})

    run()
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
        print(f"\n{r['kind']} {r['outcome']}: {r['edits']}\n    {r['detail']}")
    if args.json:
        args.json.write_text(json.dumps(records, indent=1, default=str))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
