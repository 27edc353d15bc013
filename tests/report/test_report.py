"""The report: self-contained HTML from whatever the stages wrote; metrics; opened in a real headless browser."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from pipeline.config import load_params, load_vehicle
from pipeline.report import figures, html
from stages import report as report_stage
from tests.cli.helpers import VEHICLE_YAML


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


def _write(path: Path, doc: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))


@pytest.fixture
def study_dir(run_dir: Path) -> Path:
    """The run plus the files the coupled, decoupled and simulate stages write (their real names and shapes)."""
    ev = run_dir / "data/evaluation/coupled"
    outs = ["udot_mps2", "rdot_radps2"]
    _write(run_dir / "data/models/coupled/hyperparameters.json", {
        "tuning": "nested", "tuned_on": "train_test", "n_tuning_rows": 2367, "outputs": outs,
        "inputs": ["u_mps", "n1_rpm"], "hyperparameters": {}})
    hyper = {"rbf_svr": {o: {"C": 1.0, "epsilon": 0.01, "gamma": 0.1} for o in outs},
             "wdse_svr": {o: {"C": 2.0, "epsilon": 0.02, "gammas": [0.5, 0.25]} for o in outs}}
    _write(ev / "table2.json", hyper)
    (ev / "table2.md").write_text("| Regressor | Hyperparameter | udot_mps2 |\n| --- | --- | ---: |\n"
                                  "| RBF-SVR | C | 1 |\n")

    def scores(r2: float) -> dict:
        cv = {o: {k: {"mean": r2, "sd": 0.05} for k in ("test_r2", "train_r2", "test_mae", "train_mae")}
              for o in outs}
        return {"cv": cv, "final": {o: {"r2": r2, "mae": 0.01} for o in outs}}

    _write(ev / "table3.json", {"rbf_svr": scores(0.7), "wdse_svr": scores(0.8), "mcfarland_whitcomb": scores(0.9),
                                "gertler_hagen": {"failed": {"error": "ModelError", "reason": "singular <x>"}}})
    (ev / "table3.md").write_text("| Model | Output | R2 |\n| --- | --- | ---: |\n| RBF-SVR | udot_mps2 | 0.7 |\n")
    _write(ev / "fold_scores.json", {"rbf_svr": [{"fold": 0, "test": {"udot_mps2": {"r2": 0.7}}}]})
    curve = {"train_sizes": [40, 220, 400], "test_mae_mean": [3.0, 0.8, 0.7], "train_mae_mean": [0.5, 0.7, 0.7]}
    cv = {"test_mae_mean": 0.7, "test_mae_sd": 0.1, "test_r2_mean": 0.94, "test_r2_sd": 0.02, "train_mae_mean": 0.68}
    _write(run_dir / "data/evaluation/decoupled/metrics.json", {"results": {
        "u": {"ls": {"cv": cv, "best_params": {}, "search_mae": 0.7, "learning_curve": curve},
              "gp": {"cv": {**cv, "test_mae_mean": 0.6}, "best_params": {}, "search_mae": 0.8,
                     "learned": {"kernel": "RBF([1, 2])"}, "learning_curve": curve}}}})
    sim = run_dir / "data/simulation/trial02"
    _write(sim / "free_run.json", [
        {"model": "gp", "status": "ok", "diverged_at_s": None, "band_coverage": {"u": 0.95},
         "metrics": {"u": {"r2": 0.97, "mae": 0.02}}},
        {"model": "coupled_wdse_svr", "status": "diverged", "diverged_at_s": 7.5,
         "metrics": {"u": {"r2": 0.5, "mae": 0.04}}}])
    _write(sim / "bridging.json", [
        {"window_s": 10.0, "model": "hold_last", "n_windows": 3, "n_diverged": 0, "mean_error_m": 2.0},
        {"window_s": 10.0, "model": "gp", "n_windows": 3, "n_diverged": 0, "mean_error_m": 0.5}])
    (sim / "bridging.md").write_text("| outage (s) | model |\n| ---: | --- |\n| 10 | gp |\n")
    (sim / "free_run.png").write_bytes(_png())
    return run_dir


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


def _section(text: str, anchor: str) -> str:
    return text.split(f'<section id="{anchor}">', 1)[1].split("</section>", 1)[0]


def test_study_tables_have_paper_titles_and_show_each_artifact_once(study_dir: Path) -> None:
    text = _build(study_dir).read_text()
    for title in ("Table II — hyperparameters (paper 000)", "Table III — cross-validation and final check",
                  "Table I — the damping study (paper 001)", "Fig. 2 — learning curves", "Fig. 4 — free runs"):
        assert text.count(title) == 1, title
    # each table once: no heading per file name, no Markdown + JSON twins; the JSON is a download link
    for name in ("table2.md", "table2.json", "table3.md", "table3.json", "fold_scores.json", "metrics.json",
                 "trial02/bridging.md", "trial02/bridging.json", "trial02/free_run.json"):
        assert f"<h4>{name}</h4>" not in text, name
    assert 'href="../data/evaluation/coupled/table3.json"' in text
    assert 'href="../data/simulation/trial02/bridging.json"' in text
    # the generic renderer (files no study renderer knows) still shows a Markdown/JSON pair once
    assert "<h4>table.md</h4>" in text and "<h4>cv_summary.json</h4>" in text
    coupled = _section(text, "coupled")
    assert coupled.index("RBF-SVR") < coupled.index("WDSE-SVR") < coupled.index("McFarland–Whitcomb")
    assert "gamma_n1_rpm" in coupled and "0.800 ± 0.050" in coupled  # WDSE's γ per input; mean ± sd


def test_report_names_the_tuning_protocol_and_the_ranking_that_contradicts_the_paper(study_dir: Path) -> None:
    text = _build(study_dir).read_text()
    assert "Tuning protocol: nested" in _section(text, "summary")
    assert "Differs from paper 000" in text and "McFarland–Whitcomb" in _section(text, "summary")
    hyper = study_dir / "data/models/coupled/hyperparameters.json"
    _write(hyper, {**json.loads(hyper.read_text()), "tuning": "split", "tuned_on": "tuning"})
    text = _build(study_dir).read_text()
    assert "Tuning protocol: split" in text and "the papers&#x27; protocol" in text
    t3 = study_dir / "data/evaluation/coupled/table3.json"
    doc = json.loads(t3.read_text())
    doc["mcfarland_whitcomb"]["final"] = {o: {"r2": 0.1, "mae": 1.0} for o in doc["mcfarland_whitcomb"]["final"]}
    t3.write_text(json.dumps(doc))
    assert "Differs from paper 000" not in _build(study_dir).read_text()


def test_free_run_table_has_a_model_column_and_failures_are_listed(study_dir: Path) -> None:
    text = _build(study_dir).read_text()
    sim = _section(text, "simulation")
    head = sim.split("<thead>", 1)[1].split("</thead>", 1)[0]
    assert ">model</th>" in head and ">u MAE [m/s]</th>" in head and ">2σ band coverage</th>" in head
    assert "WDSE-SVR" in sim and "diverged" in sim and "0.25×" in sim  # bridging vs hold-last
    assert "coupled_wdse_svr" not in sim  # one name per model: the report's label, not the stage's key
    quarantine = _section(text, "quarantine")
    assert "Gertler–Hagen" in quarantine and "singular &lt;x&gt;" in quarantine and "truncated" in quarantine


def test_cells_never_show_raw_json(study_dir: Path) -> None:
    assert html.fmt({"a": 1.23456, "b": [1, 2]}) == "a: 1.235; b: 1, 2"
    assert html.fmt([{"x": 1}, {"x": 2}]) == "2 records"
    text = _build(study_dir).read_text()
    visible = re.sub(r"<[^>]+>", " ", text.split("<main>", 1)[1])
    assert not re.search(r"[{\[]\s*&quot;", visible), "JSON text in the report"


CHECK = """<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  var tables = Array.from(document.querySelectorAll('table'));
  var rendered = tables.filter(function (t) { return t.rows.length > 0 && t.getBoundingClientRect().height > 0; });
  var wide = Array.from(document.querySelectorAll('.tw')).filter(function (e) {
    return e.scrollWidth > e.clientWidth + 1; }).length;
  var m = document.createElement('div');
  m.id = 'auvid-check';
  m.textContent = 'images=' + imgs.length + ' decoded=' + ok +
    ' tables=' + tables.length + ' rendered=' + rendered.length +
    ' page=' + document.documentElement.scrollWidth + '/' + window.innerWidth + ' wide=' + wide;
  document.body.appendChild(m);
});
</script>"""


def test_report_renders_in_a_headless_browser(study_dir: Path, tmp_path: Path) -> None:
    """Every image decodes, every table renders, and at 1400 px nothing scrolls sideways (page or table box)."""
    run_dir = study_dir
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    assert browser, "chromium is required for this test (apt-get install -y chromium; see .ci/run)"
    page = tmp_path / "checked.html"
    page.write_text(_build(run_dir).read_text().replace("</body>", CHECK + "</body>"))
    profile = tmp_path / "profile"
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--virtual-time-budget=5000",
           "--window-size=1400,900", "--dump-dom",
           page.as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env={**os.environ, "HOME": str(tmp_path)})
    match = re.search(r"images=(\d+) decoded=(\d+) tables=(\d+) rendered=(\d+) page=(\d+)/(\d+) wide=(\d+)",
                      proc.stdout)
    assert match, f"no check marker in the DOM; rc={proc.returncode} stderr={proc.stderr[-2000:]}"
    images, decoded, tables, rendered, page_w, view_w, wide = map(int, match.groups())
    assert images >= 6 and decoded == images
    assert tables >= 6 and rendered == tables
    assert page_w <= view_w and wide == 0, f"horizontal scrolling at {view_w} px: page {page_w}, {wide} table(s)"


# ------------------------------------------------------------ the headline box against reports/metrics.json

def headline_tables(text: str) -> list[list[dict[str, str]]]:
    """The tables of the report's headline box (the Summary section's first box), as rows of cell texts."""
    import html as stdhtml

    box = _section(text, "summary").split("<div class='box'>", 1)[1]
    tables = []
    for table in re.findall(r"<table>(.*?)</table>", box, flags=re.S):
        head = [stdhtml.unescape(h) for h in re.findall(r"<th(?:\s[^>]*)?>(.*?)</th>", table)]
        rows = [[stdhtml.unescape(c) for c in re.findall(r"<td(?:\s[^>]*)?>(.*?)</td>", tr)]
                for tr in re.findall(r"<tr>(.*?)</tr>", table.split("<tbody>", 1)[1])]
        tables.append([dict(zip(head, r, strict=True)) for r in rows])
    return tables


def _scores(metrics: dict[str, Any], study: str) -> dict[str, float]:
    """Every flattened score of one study in metrics.json, keyed ``<file>:<path>``."""
    return {f"{name}:{k}": v for name, doc in metrics.items() if name.startswith(f"{study}/") and isinstance(doc, dict)
            for k, v in doc.items()}


def _one(scores: dict[str, float], *suffixes: str, within: str = "") -> float:
    found = {k: v for k, v in scores.items() if within in k and any(k.endswith(s) for s in suffixes)}
    assert len(set(found.values())) == 1, f"{suffixes} in metrics.json: {found or 'missing'}"
    return next(iter(found.values()))


def check_headline_against_metrics(root: Path) -> int:
    """Every number of the headline box equals (as shown, 4 significant digits) the score in reports/metrics.json
    it comes from, and each "best" is the best there. Returns how many numbers were checked."""
    from pipeline.report import studies, verdicts
    from stages.report import simulation_doc

    text = (root / "reports/report.html").read_text()
    metrics = json.loads((root / "reports/metrics.json").read_text())
    dvc = json.loads((root / "reports/headline.json").read_text())
    marks = verdicts.simulation_marks(simulation_doc(root))
    model_of = {v: k for k, v in {**verdicts.COUPLED_LABELS, **verdicts.DAMPING_LABELS}.items()}
    output_of = {v: k for k, v in studies.OUTPUT_LABELS.items()}
    checked = 0
    for rows in headline_tables(text):
        for row in rows:
            if "R² on the unseen trial" in row:  # best coupled model per output
                out = output_of.get(row["output"], row["output"])
                coupled = _scores(metrics, "coupled")
                value = _one(coupled, f"{model_of.get(row['best model'], row['best model'])}.{out}.final_r2",
                             f"{model_of.get(row['best model'], row['best model'])}.final.{out}.r2")
                assert row["R² on the unseen trial"] == html.fmt(value), row
                finals = [v for k, v in coupled.items() if k.endswith((f".{out}.final_r2", f".final.{out}.r2"))]
                assert value == max(finals), (row, finals)
                assert dvc["coupled_final_r2"][out]["model"] == model_of.get(row["best model"]), (row, dvc)
                checked += 1
            elif "best damping model" in row:  # best damping model per DOF against least squares
                dof, model = row["DOF"], model_of.get(row["best damping model"], row["best damping model"])
                dec = _scores(metrics, "decoupled")
                value = _one(dec, f"results.{dof}.{model}.cv.test_mae_mean")
                ls = _one(dec, f"results.{dof}.ls.cv.test_mae_mean")
                unit = studies.DAMPING_UNIT.get(dof, "")
                assert row["CV test MAE"] == f"{value:.4g} {unit}" and row["LS (reference)"] == f"{ls:.4g} {unit}"
                # "best" is the lowest over every model, least squares (the reference) included, and it is the
                # model the DVC metric names
                # ... among the models not left out (a failed free run or a band outside its coverage)
                out_of_best = {m for m in verdicts.DAMPING_LABELS if verdicts.disqualified(marks, m, dof)}
                every = [v for k, v in dec.items()
                         if (found := re.search(rf"results\.{dof}\.([^.]+)\.cv\.test_mae_mean$", k))
                         and found.group(1) not in out_of_best]
                assert value == min(every), (row, every)
                assert dvc["damping_mae"][dof]["model"] == model, (row, dvc["damping_mae"])
                assert row["vs LS"] == f"{value / ls:.2f}×"
                checked += 2
            elif "vs hold-last" in row:  # DVL-outage bridging
                sim = _scores(metrics, "simulation")
                window = float(row["outage [s]"])
                key = model_of.get(row["best model"], row["best model"])
                value = _one(sim, f"{key}@window_s={window}.mean_error_m", within=row["trial"])
                hold = _one(sim, f"hold_last@window_s={window}.mean_error_m", within=row["trial"])
                assert row["mean error [m]"] == html.fmt(value) and row["vs hold-last"] == f"{value / hold:.2f}×"
                checked += 2
    return checked


@pytest.fixture
def headline_run(study_dir: Path) -> Path:
    """study_dir with the coupled stage's metrics.json (stages.train writes it beside table3.json)."""
    t3 = json.loads((study_dir / "data/evaluation/coupled/table3.json").read_text())
    _write(study_dir / "data/evaluation/coupled/metrics.json", {
        m: {o: {"cv_test_r2": e["cv"][o]["test_r2"]["mean"], "cv_test_r2_sd": e["cv"][o]["test_r2"]["sd"],
                "final_r2": e["final"][o]["r2"]} for o in e["final"]} if "final" in e else
        {"failed": "ModelError: singular"} for m, e in t3.items()})
    dec_path = study_dir / "data/evaluation/decoupled/metrics.json"
    dec = json.loads(dec_path.read_text())
    svr = json.loads(json.dumps(dec["results"]["u"]["gp"]))  # a second model beside LS, worse than GP
    svr["cv"]["test_mae_mean"] = 0.66
    dec["results"]["u"]["svr"] = svr
    _write(dec_path, dec)
    return study_dir


def test_headline_numbers_match_reports_metrics_json(headline_run: Path) -> None:
    _build(headline_run)
    assert check_headline_against_metrics(headline_run) == 2 + 2 + 2  # two outputs, one DOF, one outage


def test_headline_check_catches_a_number_that_is_not_in_metrics_json(headline_run: Path) -> None:
    _build(headline_run)
    metrics_path = headline_run / "reports/metrics.json"
    metrics = json.loads(metrics_path.read_text())
    metrics["decoupled/metrics"]["results.u.gp.cv.test_mae_mean"] = 0.65  # the box says 0.6
    metrics_path.write_text(json.dumps(metrics))
    with pytest.raises(AssertionError):
        check_headline_against_metrics(headline_run)
