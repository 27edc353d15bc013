"""The report's table of the targets' spectra against their inputs' (the derive stage's
``data/derived/<trial>.spectra.json``, :mod:`pipeline.estimation.spectral`): per trial and target, the share of
its variance above the actuators' band, how much of it no input explains, the narrow-band peaks there, and the
remedy for each flagged target."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from pipeline.estimation.spectral import report_path
from pipeline.layout import estimation_report_path
from pipeline.report import html as H
from pipeline.report.names import signal_label

log = logging.getLogger(__name__)


def _read(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        log.warning("report: cannot read %s: %s", path, err)
        return None


def section(root: Path, trials: list[str], metrics: dict[str, Any]) -> str:
    """One table over every trial's targets, the disturbances the differentiate stage removed and the check's
    warnings (with their remedy) above it; '' without any check."""
    rows, warnings, limit, peak = [], [], 0.0, 0.0
    removed = _removed(root, trials, metrics)
    for trial in trials:
        path = report_path(root, trial)
        doc = _read(path) if path.exists() else None
        if not doc:
            continue
        limit, peak = doc.get("share_limit") or 0.0, doc.get("peak_limit") or 0.0
        for entry in (doc.get("dofs") or {}).values():
            for col, target in (entry.get("targets") or {}).items():
                peaks = ", ".join(f"{p['frequency_hz']:.2f} Hz ({100 * p['share']:.0f} %)"
                                  for p in target.get("peaks") or [])
                rows.append({"trial": trial, "target": signal_label(col), "inputs": ", ".join(entry.get("inputs", [])),
                             "inputs' band [Hz]": entry.get("input_band_hz"),
                             "checked above [Hz]": entry.get("band_hz"),
                             "share above the band": target.get("share_above_band"),
                             "unexplained by the inputs": target.get("unexplained_above_band"),
                             "narrow-band peaks above the band": peaks or "none",
                             "flag": "check" if target.get("flagged") else ""})
                metrics.setdefault("target_spectra", {}).setdefault(trial, {})[col] = round(
                    float(target.get("unexplained_above_band", 0.0)), 6)
        warnings += [w.get("text", "") for w in doc.get("warnings") or []]
    if not rows:
        return ""
    parts = ["<h3>Targets against what the actuators can do</h3>"]
    parts += [f"<p class='warn'>{H.esc(text)}</p>" for text in removed + warnings]
    parts.append(H.table(rows, caption=(
        "Each target's variance above twice the band where its inputs (its tau, the thrusts and actuator signals) "
        "put 98 % of theirs; a target is marked check where more than "
        f"{100 * limit:.0f} % of its variance lies there unexplained by the inputs, or a narrow-band peak "
        f"holds more than {100 * peak:.0f} % (a vibration the smoother passed on: differentiate.notch_hz / "
        "max_hz remove it; docs/estimation.md)")))
    return "".join(parts)


def _removed(root: Path, trials: list[str], metrics: dict[str, Any]) -> list[str]:
    """The differentiate stage's removed disturbances (``differentiate.disturbances: remove``), one sentence each;
    ``metrics["disturbances_removed"]``: trial -> target -> frequency (Hz)."""
    out = []
    for trial in trials:
        path = estimation_report_path(root, trial)
        doc = _read(path) if path.exists() else None
        for found in (doc or {}).get("disturbances") or []:
            out.append(f"{trial}: {found.get('text', '')}")
            metrics.setdefault("disturbances_removed", {}).setdefault(trial, {})[found.get("target", "")] = round(
                float(found.get("frequency_hz", 0.0)), 4)
    return out
