"""The report's table of the targets' spectra (pipeline.report.spectra) from the derive stage's
<trial>.spectra.json: a trial whose u̇ carries a 2.3-Hz ringing is named with its remedy, a clean one is not."""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.estimation.spectral import check_targets, report_path
from pipeline.tableio import write_json
from tests.estimation.test_spectral import _trial
from tests.report.test_report import _build, _section


def test_the_report_names_the_ringing_and_its_remedy(run_dir: Path) -> None:
    for trial, amp in (("trial01", 0.01), ("trial02", 0.0)):
        table, _ = _trial(0, amp)
        report_path(run_dir, trial).parent.mkdir(parents=True, exist_ok=True)
        write_json(check_targets(table, trial), report_path(run_dir, trial))
    text = _section(_build(run_dir).read_text(), "estimation")
    assert "Targets against what the actuators can do" in text
    warnings = [w for w in text.split("<p class='warn'>")[1:]]
    assert len(warnings) == 1 and warnings[0].startswith("trial01: u̇ carries")
    assert "narrow-band disturbance at 2.30 Hz" in warnings[0] and "differentiate.notch_hz: [2.30]" in warnings[0]
    assert "surge acceleration u̇" in text and "2.30 Hz (" in text and ">check<" in text
    metrics = json.loads((run_dir / "reports/metrics.json").read_text())
    assert metrics["target_spectra"]["trial01"]["udot_mps2"] > 0.05
    assert metrics["target_spectra"]["trial02"]["udot_mps2"] < 0.05


def test_no_check_no_table(run_dir: Path) -> None:
    assert "Targets against what the actuators can do" not in _build(run_dir).read_text()
