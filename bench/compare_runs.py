"""Compare two run directories file by file and name every file that differs beyond its timing fields.

    python bench/compare_runs.py RUN_A RUN_B            # e.g. two `auvid demo --out` directories

A change that only moves code (a re-layout) must leave every Parquet, JSON, model and figure file identical. Files
are compared byte for byte; a JSON file that differs is compared again with its timing fields (keys naming a time,
a duration or a rate of work, listed in ``TIMING_KEYS``) removed, and reported as "timing only" when nothing else
differs. Parquet files that differ are compared again by content (schema, metadata and values) so that the report
says whether the data or only the file's bytes moved. Exit status 0 when nothing but timing differs, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

#: JSON keys whose values are measured times, not results.
TIMING_KEYS = re.compile(r"(^|_)(time|times|timing|timings|seconds|elapsed|wall|cpu|duration|started|finished|"
                         r"fit_time|score_time|predict_time|fit_s|predict_s|s_per_fit|rows_per_s|created|date)($|_)",
                         re.IGNORECASE)
#: A report table's column of measured times (by its header), and a figure of them (by its alt text).
TIMING_HEADER = re.compile(r"time|longest fit", re.IGNORECASE)
TIMING_FIGURE = re.compile(r'<img alt="[^"]*timing[^"]*" src="[^"]*"', re.IGNORECASE)
#: Files whose content is a timing or a log by nature.
TIMING_FILES = re.compile(r"(timings?\.json|timings?\.png|\.log)$")


def _strip(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {k: _strip(v) for k, v in doc.items() if not TIMING_KEYS.search(str(k))}
    if isinstance(doc, list):
        return [_strip(v) for v in doc]
    return doc


def _json_diff(a: Path, b: Path) -> str:
    try:
        da, db = json.loads(a.read_text()), json.loads(b.read_text())
    except ValueError:
        return "differs (not JSON)"
    return "timing only" if _strip(da) == _strip(db) else "differs"


def _cells(row: str) -> list[str]:
    return re.split(r"(?=<t[dh][ >])", row)


def html_without_timing(text: str) -> str:
    """The report with its timing columns emptied and its timing figures dropped."""
    def table(match: re.Match[str]) -> str:
        rows = re.split(r"(?=<tr[ >])", match.group(0))
        header = next((r for r in rows if re.search(r"<th[ >]", r)), "")
        drop = {i for i, c in enumerate(_cells(header)) if TIMING_HEADER.search(re.sub(r"<[^>]+>", "", c))}
        if not drop:
            return match.group(0)
        return "".join("".join("<td>" if i in drop and not re.match(r"<th[ >]", c) else c
                               for i, c in enumerate(_cells(r))) for r in rows)
    return TIMING_FIGURE.sub("<img>", re.sub(r"<table.*?</table>", table, text, flags=re.S))


def _html_diff(a: Path, b: Path) -> str:
    same = html_without_timing(a.read_text()) == html_without_timing(b.read_text())
    return "timing only" if same else "differs"


def _parquet_diff(a: Path, b: Path) -> str:
    import pyarrow.parquet as pq

    ta, tb = pq.read_table(a), pq.read_table(b)
    if ta.schema.metadata != tb.schema.metadata:
        return "differs (metadata)"
    return "bytes differ, same content" if ta.equals(tb) else "differs (values)"


def compare(run_a: Path, run_b: Path) -> list[tuple[str, str]]:
    """``[(relative path, verdict)]`` for every file that is not byte-identical in both runs."""
    files_a = {p.relative_to(run_a) for p in run_a.rglob("*") if p.is_file()}
    files_b = {p.relative_to(run_b) for p in run_b.rglob("*") if p.is_file()}
    out = []
    for rel in sorted(files_a | files_b):
        if rel not in files_b:
            out.append((str(rel), "only in A"))
            continue
        if rel not in files_a:
            out.append((str(rel), "only in B"))
            continue
        a, b = run_a / rel, run_b / rel
        if a.read_bytes() == b.read_bytes():
            continue
        if TIMING_FILES.search(rel.name):
            verdict = "timing only"
        elif rel.suffix == ".json":
            verdict = _json_diff(a, b)
        elif rel.suffix == ".html":
            verdict = _html_diff(a, b)
        elif rel.suffix == ".parquet":
            verdict = _parquet_diff(a, b)
        else:
            verdict = "differs"
        out.append((str(rel), verdict))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run_a", type=Path)
    ap.add_argument("run_b", type=Path)
    args = ap.parse_args(argv)
    diffs = compare(args.run_a, args.run_b)
    n = sum(1 for p in args.run_a.rglob("*") if p.is_file())
    for rel, verdict in diffs:
        print(f"{verdict:28s} {rel}")
    real = [d for d in diffs if d[1] != "timing only"]
    print(f"{n} files in A; {len(diffs)} not byte-identical, {len(real)} beyond timing fields")
    return 1 if real else 0


if __name__ == "__main__":
    sys.exit(main())
