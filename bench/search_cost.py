"""Per search of a run's tune stage: its candidates' cost, its slowest fit over its median fit, and how many
candidates libsvm's iteration caps stopped (from ``data/evaluation/coupled/search_trace.json``).

    python bench/search_cost.py RUN            # RUN: a run directory after `auvid run --to tune` (or `auvid demo`)
    python bench/search_cost.py RUN OTHER      # two runs side by side (e.g. with and without the relative cap)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def searches(run: Path) -> dict[str, dict]:
    doc = json.loads((run / "data/evaluation/coupled/search_trace.json").read_text())
    return {f"{model} {output}": res for model, by_output in doc.items() for output, res in by_output.items()
            if isinstance(res, dict) and res.get("trace")}


def fits(entry: dict, res: dict) -> int:
    """The fits a trace entry's CPU counts (runs before the entries carried ``n_fits``: a screen's entry its
    folds' R², a survivor the folds the screen left out)."""
    if "n_fits" in entry:
        return entry["n_fits"]
    if "fold_r2" in entry:
        return len(entry["fold_r2"])
    screen = (res.get("halving") or {}).get("screen_folds") or []
    return res["n_folds"] - len(screen) if entry.get("rung") == 1 and screen else res["n_folds"]


def row(res: dict) -> str:
    trace = res["trace"]
    per_fit = np.array([t["cpu_s"] / fits(t, res) for t in trace if fits(t, res)])
    cpu = sum(t["cpu_s"] for t in trace)
    capped = sum(1 for t in trace if t["capped"])
    ratio = per_fit.max() / np.median(per_fit) if per_fit.size else float("nan")
    return f"{cpu:.1f} | {ratio:.1f} | {capped} | {res['best_score']:.4f}"


def main(runs: list[Path]) -> None:
    tables = [searches(r) for r in runs]
    head = " | ".join(f"{r.name}: CPU s | slowest fit / median | capped | tuning R²" for r in runs)
    print(f"| search | {head} |")
    print("| --- |" + " ---: | ---: | ---: | ---: |" * len(runs))
    for name in tables[0]:
        print(f"| {name} | " + " | ".join(row(t[name]) if name in t else "– | – | – | –" for t in tables) + " |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main([Path(a) for a in sys.argv[1:]])
