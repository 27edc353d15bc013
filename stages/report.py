"""Stage report: everything under ``data/`` -> ``reports/report.html`` (self-contained), ``reports/metrics.json``
(for ``dvc metrics``), ``reports/plots/*.json`` (for ``dvc plots``) and ``reports/figures/*.png``.

``python -m stages.report --root RUN --vehicle vehicle.yaml``.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from pipeline import layout
from pipeline.config import Params, Vehicle
from pipeline.report.build import build
from pipeline.tableio import atomic_path, write_json
from stages.common import StageResult, stage_main

log = logging.getLogger(__name__)

NAME = "report"


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_")


def run(root: Path, vehicle: Vehicle, params: Params) -> StageResult:
    """Build the self-contained HTML report, metrics.json and the plot data of the run."""
    root = Path(root)
    report = build(root, vehicle, params)
    out = root / layout.REPORTS
    outputs = []
    with atomic_path(out / "report.html") as tmp:
        tmp.write_text(report.html, encoding="utf-8")
        tmp.chmod(0o644)  # a report is for reading (mkstemp makes 0600)
    outputs.append(out / "report.html")
    outputs.append(write_json(report.metrics, out / "metrics.json"))
    for name, rows in sorted(report.plots.items()):
        outputs.append(write_json(rows, out / "plots" / f"{name}.json"))
    for path in outputs:
        path.chmod(0o644)
    figdir = out / "figures"
    wanted = {f"{_safe(name)}" + ("" if name.endswith(".png") else ".png") for name in report.figures}
    if figdir.is_dir():
        for old in figdir.glob("*.png"):
            if old.name not in wanted:
                old.unlink()
    for name, png in sorted(report.figures.items()):
        target = figdir / (_safe(name) + ("" if name.endswith(".png") else ".png"))
        with atomic_path(target) as tmp:
            tmp.write_bytes(png)
            tmp.chmod(0o644)
        outputs.append(target)
    log.info("report: %s", out / "report.html")
    return StageResult(stage=NAME, outputs=outputs, summary={"report": str(out / "report.html"),
                                                             "figures": len(report.figures)})


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
