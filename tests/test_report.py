"""The report: self-contained HTML from whatever the stages wrote; metrics; opened in a real headless browser."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fakestages import VEHICLE_YAML

from pipeline.config import load_params, load_vehicle
from pipeline.report import figures
from stages import report as report_stage


def _png() -> bytes:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([0, 1], [1, 0])
    return figures.png_bytes(fig)


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    root = tmp_path / "run"
    (root / "vehicle.yaml").parent.mkdir(parents=True)
    (root / "vehicle.yaml").write_text(VEHICLE_YAML)
    for trial in ("trial01", "trial02"):
        sig = root / "data/signals" / trial
        sig.mkdir(parents=True)
        (sig / "ingest_report.json").write_text(json.dumps({
            "trial": trial, "source_file": f"data/raw/{trial}.mcap", "source_sha256": "ab" * 32, "format": "mcap",
            "salvage": None, "failed_topics": {}, "topics": {"/nav": {"read": 100, "stored": 100}},
            "streams": {"nav": {"topic": "/nav", "clock": "log", "offset_s": 0.0, "count": 100, "span_s": 9.9,
                                "mean_rate_hz": 10.0, "largest_gap_s": 0.5, "steps_back": 0},
                        "fog": {"topic": "/fog", "clock": "log", "offset_s": 0.0, "count": 1000, "span_s": 9.99,
                                "mean_rate_hz": 100.0, "largest_gap_s": 0.01, "steps_back": 0}}}))
        n = 200
        t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 50_000_000
        valid = np.ones(n, dtype=bool)
        valid[80:100] = False
        frame = pd.DataFrame({"t_ns": t, "u_mps": np.sin(t / 1e9), "u_mps__valid": valid,
                              "r_radps": np.cos(t / 1e9), "r_radps__valid": np.ones(n, dtype=bool),
                              "segment": np.where(valid, 0, -1).astype(np.int32)})
        (root / "data/synced").mkdir(parents=True, exist_ok=True)
        frame.to_parquet(root / f"data/synced/{trial}.parquet")
    (root / "data/signals/quarantine.json").write_text(json.dumps({"quarantined": [
        {"trial": "trial03", "file": "data/raw/trial03.mcap", "error": "IngestError", "reason": "truncated <b>",
         "topic": None, "field": None}]}))
    ev = root / "data/evaluation/coupled"
    ev.mkdir(parents=True)
    (ev / "cv_summary.json").write_text(json.dumps({
        "wdse_svr": {"udot_mps2": {"test": {"r2_mean": 0.91, "r2_sd": 0.02}, "fit_time_s": 1.5}},
        "gertler_hagen": {"udot_mps2": {"test": {"r2_mean": 0.84, "r2_sd": 0.03}, "fit_time_s": 0.1}}}))
    (ev / "boxplot_r2.png").write_bytes(_png())
    (ev / "table.md").write_text("# R2\n\n| model | R2 |\n| --- | --- |\n| wdse_svr | 0.91 |\n| gh | 0.84 |\n")
    dec = root / "data/evaluation/decoupled"
    dec.mkdir(parents=True)
    (dec / "folds.json").write_text(json.dumps([{"model": "ls", "fold": 0, "r2": 0.7}, {"model": "gp", "fold": 0,
                                                                                      "r2": 0.8}]))
    sim = root / "data/simulation"
    sim.mkdir(parents=True)
    (sim / "rollout_trial02.csv").write_text("t_s,u_meas,u_pred\n0,0.1,0.1\n1,0.2,0.19\n")
    (sim / "bridging.json").write_text(json.dumps({"outage_30s": {"position_error_m": 1.2}}))
    (sim / "rollout.png").write_bytes(_png())
    return root


def _build(root: Path) -> Path:
    vehicle = load_vehicle(root / "vehicle.yaml")
    result = report_stage.run(root, vehicle, load_params(None))
    assert result.exit_code == 0
    return root / "reports/report.html"


def test_report_is_self_contained_and_complete(run_dir: Path) -> None:
    path = _build(run_dir)
    text = path.read_text()
    assert not re.search(r"""(src|href)=["'](https?:|//)""", text), "no network references"
    assert "<link" not in text and "<script" not in text
    imgs = re.findall(r'<img [^>]*src="data:image/png;base64,', text)
    assert len(imgs) >= 2 + 2 + 2  # signals per trial, rates per trial, stage PNGs
    for needle in ("trial01", "trial02", "trial03", "truncated &lt;b&gt;", "wdse_svr", "boxplot_r2.png",
                   "rollout_trial02.csv", "position_error_m", "Provenance", "0.1.0", "ab" * 32):
        assert needle in text, needle
    metrics = json.loads((run_dir / "reports/metrics.json").read_text())
    assert metrics["ingest"] == {"trials": 2, "quarantined": 1}
    assert metrics["coupled/cv_summary"]["wdse_svr.udot_mps2.test.r2_mean"] == 0.91
    assert metrics["simulation/bridging"]["outage_30s.position_error_m"] == 1.2
    plots = json.loads((run_dir / "reports/plots/valid_fraction.json").read_text())
    assert {"trial": "trial01", "signal": "u_mps", "valid_fraction": 0.9} in plots
    assert list((run_dir / "reports/figures").glob("signals_trial01.png"))


def test_report_is_deterministic(run_dir: Path) -> None:
    first = _build(run_dir).read_bytes()
    metrics = (run_dir / "reports/metrics.json").read_bytes()
    assert _build(run_dir).read_bytes() == first
    assert (run_dir / "reports/metrics.json").read_bytes() == metrics


def test_report_of_an_empty_run_says_so(tmp_path: Path) -> None:
    (tmp_path / "vehicle.yaml").write_text(VEHICLE_YAML)
    text = _build(tmp_path).read_text()
    assert "No synced trial found" in text and "stage not run" in text


CHECK = """<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  var tables = Array.from(document.querySelectorAll('table'));
  var rendered = tables.filter(function (t) { return t.rows.length > 0 && t.getBoundingClientRect().height > 0; });
  var m = document.createElement('div');
  m.id = 'auvid-check';
  m.textContent = 'images=' + imgs.length + ' decoded=' + ok +
    ' tables=' + tables.length + ' rendered=' + rendered.length;
  document.body.appendChild(m);
});
</script>"""


def test_report_renders_in_a_headless_browser(run_dir: Path, tmp_path: Path) -> None:
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    assert browser, "chromium is required for this test (apt-get install -y chromium; see .ci/run)"
    page = tmp_path / "checked.html"
    page.write_text(_build(run_dir).read_text().replace("</body>", CHECK + "</body>"))
    profile = tmp_path / "profile"
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--virtual-time-budget=5000", "--dump-dom",
           page.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env={**os.environ, "HOME": str(tmp_path)})
    match = re.search(r"images=(\d+) decoded=(\d+) tables=(\d+) rendered=(\d+)", proc.stdout)
    assert match, f"no check marker in the DOM; rc={proc.returncode} stderr={proc.stderr[-2000:]}"
    images, decoded, tables, rendered = map(int, match.groups())
    assert images >= 6 and decoded == images
    assert tables >= 6 and rendered == tables
