"""Planted failures: a model worse than the mean on its own training rows, a GP band that covers 50 %, a free run
and a bridging window that diverged. Each is marked in every table that shows the model, left out of "best"
(the summary's choice is headline.json's, model by model), and a box plot whose model falls off scale says so."""

from __future__ import annotations

import json
import re
from pathlib import Path

from pipeline.report import coupled as report_coupled
from pipeline.report import figures, verdicts
from pipeline.units import axis_label
from tests.report.test_report import _build, _section, _write, headline_tables
from tests.report.test_verdicts import _visible

SECTIONS = ("coupled", "decoupled", "simulation")


def _tables(text: str, section: str) -> list[list[dict[str, str]]]:
    """The section's tables (before "Other files") as rows of visible cell texts."""
    body = _section(text, section).split("<h3>Other files</h3>", 1)[0]
    out = []
    for table in re.findall(r"<table>(.*?)</table>", body, flags=re.S):
        head = [_visible(h).strip() for h in re.findall(r"<th(?:\s[^>]*)?>(.*?)</th>", table)]
        rows = [[_visible(c).strip() for c in re.findall(r"<td(?:\s[^>]*)?>(.*?)</td>", tr)]
                for tr in re.findall(r"<tr>(.*?)</tr>", table.split("<tbody>", 1)[1])]
        out.append([dict(zip(head, r, strict=True)) for r in rows])
    return out


def _plant(root: Path) -> None:
    t3_path = root / "data/evaluation/coupled/table3.json"
    t3 = json.loads(t3_path.read_text())
    t3["mcfarland_whitcomb"]["cv"]["rdot_radps2"]["train_r2"] = {"mean": -3.4, "sd": 5.8}  # best on ṙ otherwise
    _write(t3_path, t3)
    folds = {m: [{"fold": k, "test": {o: {"r2": r2 + 0.01 * k} for o in ("udot_mps2", "rdot_radps2")}}
                 for k in range(3)] for m, r2 in (("rbf_svr", 0.7), ("wdse_svr", 0.8), ("mcfarland_whitcomb", 0.9))}
    folds["mcfarland_whitcomb"][0]["test"]["rdot_radps2"]["r2"] = -27.0
    _write(root / "data/evaluation/coupled/fold_scores.json", folds)
    sim = root / "data/simulation/trial02"
    runs = json.loads((sim / "free_run.json").read_text())
    runs[0]["band_coverage"] = {"u": 0.5}  # GP: a 2σ band that holds half the samples
    _write(sim / "free_run.json", runs)
    bridging = json.loads((sim / "bridging.json").read_text())
    bridging.append({"window_s": 10.0, "model": "svr", "n_windows": 3, "n_diverged": 1, "mean_error_m": 0.3})
    _write(sim / "bridging.json", bridging)


def test_planted_failures_are_marked_wherever_the_model_appears_and_left_out_of_best(headline_run: Path) -> None:
    _plant(headline_run)
    text = _build(headline_run).read_text()
    tables = {s: _tables(text, s) for s in SECTIONS}
    marked = {"McFarland–Whitcomb": "failed: train R² < 0", "WDSE-SVR": "diverged", "GP": "over-confident",
              "SVR": "diverged in 1 of 3 windows"}
    seen: dict[str, int] = {}
    for section, found in tables.items():
        for rows in found:
            model = ""
            for row in rows:
                model = row.get("model") or model  # Table III names a model on its first output's row only
                if model in marked and "verdict" in row:
                    if model == "McFarland–Whitcomb" and not row["output"].startswith("ṙ"):
                        assert row["verdict"] == "ok", row
                        continue
                    assert marked[model] in row["verdict"], (section, row)
                    seen[model] = seen.get(model, 0) + 1
                elif model in marked:
                    raise AssertionError(f"a table in {section} shows {model} without a verdict: {row}")
    # McFarland–Whitcomb: Table III's ṙ row; GP: Table I, the free-run and the bridging table; WDSE-SVR: Table
    # III's two rows (a diverged free run fails every output) and the free-run table; SVR: Table I and bridging
    assert seen == {"McFarland–Whitcomb": 1, "GP": 3, "WDSE-SVR": 3, "SVR": 2}, seen
    # "best": McFarland–Whitcomb failed on ṙ, WDSE-SVR's free run diverged -> RBF-SVR; SVR's bridging diverged
    summary = headline_tables(text)
    best = {r["output"]: r["best model"] for rows in summary for r in rows if "R² on the unseen trial" in r}
    assert best == {"u̇ [m/s²]": "McFarland–Whitcomb", "ṙ [rad/s²]": "RBF-SVR"}
    # bridging: SVR diverged in a window, GP's band misses its coverage: no model is recommended
    assert [r["best model"] for rows in summary for r in rows if "vs hold-last" in r] == []
    # ... the same choice as the DVC metric, model by model
    dvc = json.loads((headline_run / "reports/headline.json").read_text())
    key = {v: k for k, v in {**verdicts.COUPLED_LABELS, **verdicts.DAMPING_LABELS}.items()}
    output = {"u̇ [m/s²]": "udot_mps2", "ṙ [rad/s²]": "rdot_radps2"}
    assert {output[o]: key[m] for o, m in best.items()} == {o: v["model"] for o, v in dvc["coupled_final_r2"].items()}
    damping = {r["DOF"]: key[r["best damping model"]] for rows in summary for r in rows if "best damping model" in r}
    # GP has the lowest MAE on u but its band misses its coverage: left out, least squares is best
    assert damping == {d: v["model"] for d, v in dvc["damping_mae"].items()} == {"u": "ls"}
    # the summary says why, and names the band that misses its coverage
    box = _visible(_section(text, "summary"))
    assert "GP free run on trial02: 2σ band over-confident on u (covers 50%, target 90%–98%)" in box
    assert "WDSE-SVR free run on trial02: diverged at 7.5 s" in box
    # Fig. 4: drawn again, the failed model named, the axis clipped and the model cut off named
    caption = _visible(_section(text, "coupled").split("Fig. 4", 1)[1].split("</figcaption>", 1)[0])
    assert "red: failed (McFarland–Whitcomb on ṙ [rad/s²]" in caption
    assert "McFarland–Whitcomb: fold R² down to -27, off scale" in caption


def test_one_line_verdict_per_output_with_the_size_of_the_evidence(headline_run: Path) -> None:
    text = _build(headline_run).read_text()
    lines = [_visible(li).strip() for li in re.findall(r"<li>(.*?)</li>", _section(text, "summary"))]
    # two synced trials of 200 samples at 20 Hz (9.95 s each), 90 % of the samples in a usable segment
    evidence = "evidence: 2 trial(s), 1 of them unseen (trial02), 0.3 min, 90% usable"
    assert lines == [f"u̇ [m/s²]: McFarland–Whitcomb is best, R² 0.9 on the unseen trial (good) — {evidence}",
                     f"ṙ [rad/s²]: McFarland–Whitcomb is best, R² 0.9 on the unseen trial (good) — {evidence}",
                     f"damping d_u: GP is best, CV MAE 0.6 N, 0.86× least squares' — {evidence}"]


def test_a_box_plot_clips_a_failed_model_off_scale_and_names_it() -> None:
    scores = {"wdse_svr": {"rdot_radps2": [0.9, 0.92, 0.95]},
              "gertler_hagen": {"rdot_radps2": [-27.0, -1.5, 0.4]}}
    fig, notes = report_coupled.fold_figure(scores, ["rdot_radps2"], {("gertler_hagen", "rdot_radps2"): "x"})
    ax = fig.axes[0]
    low, high = ax.get_ylim()
    assert -1.2 < low < -1.0 and high >= 1.0  # readable: the others' boxes are not squashed to a line
    assert notes == [f"Gertler–Hagen: fold R² down to -27, off scale ({axis_label('rdot_radps2')})"]
    assert any("Gertler–Hagen: fold R² down to -27, off scale" in t.get_text() for t in ax.texts)
    ticks = [t.get_text() for t in ax.get_xticklabels()]
    assert ticks == ["WDSE-SVR", "Gertler–Hagen\n(failed: train R² < 0)"]
    figures.png_bytes(fig)


def test_the_bridging_figure_marks_failed_models_without_crowding_out_its_axes() -> None:
    """The reasons a model failed are the report's verdicts; in the legend it is "(failed)", dotted and hollow,
    so that long reasons (a divergence time, an R² below the mean's) never squeeze the axes to nothing, which
    matplotlib warns about on the user's terminal."""
    import warnings

    from pipeline.report.rollout import bridging_figure

    models = ["hold_last", "rbf_svr", "two_weights_svr", "wdse_svr", "graybox", "ls", "mlp", "krr", "svr", "gp"]
    rows = [{"model": m, "window_s": w, "mean_error_m": 0.1 * w * (k + 1), "n_windows": 14,
             "n_diverged": 2 if m == "mlp" else 0} for k, m in enumerate(models) for w in (10.0, 30.0)]
    why = "R² below the mean predictor's on the unseen trial (-0.21); the free run diverged at t = 135.40 s"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = bridging_figure(rows, {m: why for m in models[1:6]})
        figures.png_bytes(fig)
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert sum(t.endswith(" (failed)") for t in texts) == 6  # five given, and the one that diverged in a window
    lines = {t.get_label(): t for t in fig.axes[0].get_lines()}
    assert all(lines[t].get_linestyle() == ":" and lines[t].get_markerfacecolor() == "none"
               for t in texts if t.endswith(" (failed)"))
