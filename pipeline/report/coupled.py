"""The coupled study's tables and figure (paper 000): Table II (chosen hyperparameters, stages.tune), Table III (CV
and final-check R² per model and output) and the Fig. 4-like box plot of the fold test R² (stages.train; the
report draws it again with the report's verdicts: failed models red, an axis clipped at R² −1 with the model cut
off named)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from pipeline.report.verdicts import label
from pipeline.units import axis_label

MODEL_LABELS = {"rbf_svr": "RBF-SVR", "two_weights_svr": "2-weights-SVR", "wdse_svr": "WDSE-SVR",
                "gertler_hagen": "Gertler-Hagen", "mcfarland_whitcomb": "McFarland-Whitcomb",
                "fossen": "Fossen", "graybox": "Gray-box (MW + WDSE)", "graybox_gh": "Gray-box (GH + WDSE)",
                "graybox_fossen": "Gray-box (Fossen + WDSE)", "abkowitz": "Abkowitz",
                "graybox_abkowitz": "Gray-box (Abkowitz + WDSE)"}  # the Markdown tables' (ASCII hyphens)


def table2(hyper: dict[str, dict[str, dict[str, Any]]], outputs: Sequence[str], inputs: Sequence[str]) -> str:
    """Table II-like markdown: chosen hyperparameters per model and output (gammas on standardized inputs); a gray
    box's residual kept or dropped per output, with the CV R² that decided (:func:`pipeline.models.graybox.
    residual_verdict`)."""
    lines = ["| Regressor | Hyperparameter | " + " | ".join(outputs) + " |",
             "| --- | --- | " + " | ".join("---:" for _ in outputs) + " |"]
    for model, per_out in hyper.items():
        first = per_out[outputs[0]]
        rows: list[tuple[str, list[float]]] = [("epsilon", [per_out[o]["epsilon"] for o in outputs]),
                                               ("C", [per_out[o]["C"] for o in outputs])]
        if all("C_rows" in per_out[o] for o in outputs):  # the rows that C was chosen on (svr.scaled_C)
            rows.append(("C chosen on rows", [per_out[o]["C_rows"] for o in outputs]))
        if "gammas" in first:
            rows += [(f"gamma_{inp}", [per_out[o]["gammas"][i] for o in outputs]) for i, inp in enumerate(inputs)]
        else:
            rows += [(k, [per_out[o][k] for o in outputs]) for k in first if k.startswith("gamma")]
        for k, (name, vals) in enumerate(rows):
            label = MODEL_LABELS.get(model, model) if k == 0 else ""
            lines.append(f"| {label} | {name} | " + " | ".join(f"{v:.3g}" for v in vals) + " |")
        if all("residual" in per_out[o] for o in outputs):  # a gray box: its residual kept or dropped per output
            lines.append("|  | residual | " + " | ".join(per_out[o]["residual"] for o in outputs) + " |")
    return "\n".join(lines) + "\n"


def table3(results: dict[str, Any], outputs: Sequence[str], failed: dict[str, dict[str, str]] | None = None
           ) -> tuple[str, dict[str, Any]]:
    """Table III-like markdown + JSON: CV R² (train/test mean, SD) per model and output, MAE, final check, the
    90 % prediction interval (± half-width) and the share of the test trial(s)' targets inside it; a gray box
    against its base on the CV's folds and held-out trials per output under the table (JSON: ``residual``). The
    models in ``failed`` are named under the table (JSON: ``{model: {"failed": entry}}``)."""
    lines = ["| Model | Output | train R² mean | train R² SD | test R² mean | test R² SD | test MAE mean | "
             "final-check R² | 90 % interval ± | final check: inside 90 % |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    doc: dict[str, Any] = {}
    for model, res in results.items():
        doc[model] = {"cv": res["summary"], "final": res["final"], "interval": res.get("interval") or {}}
        if res.get("residual"):  # a gray box against its base on the CV's folds and held-out trials, per output
            doc[model]["residual"] = res["residual"]
        for out in outputs:
            s = res["summary"][out]
            final = f"{res['final'][out]['r2']:.3f}" if res["final"] else "n/a"
            inside = (res["final"] or {}).get(out, {}).get("interval_coverage")
            lines.append(f"| {MODEL_LABELS.get(model, model)} | {out} | {s['train_r2']['mean']:.3f} | "
                         f"{s['train_r2']['sd']:.3f} | {s['test_r2']['mean']:.3f} | {s['test_r2']['sd']:.3f} | "
                         f"{s['test_mae']['mean']:.4g} | {final} | {interval_text(doc[model]['interval'].get(out))} | "
                         f"{'n/a' if inside is None else f'{inside:.0%}'} |")
    if results:
        lines.append("\n90 % interval: the prediction p ± a half-width a + b·abs(p) (split conformal on the "
                     "blocked CV's out-of-fold |residuals|, their spread growing with abs(p); with two or more "
                     "training trials the wider of that and the quantile of fits without whole trials); inside: "
                     "the share of the test trial(s)' measured targets within it (85–95 % expected).")
    for model, res in results.items():
        if res.get("residual"):
            lines.append(f"\n{MODEL_LABELS.get(model, model)} against its own base (CV folds, held-out trials): "
                         + "; ".join(f"{out}: {rec['verdict']}" for out, rec in res["residual"].items()) + ".")
    for model, entry in (failed or {}).items():
        doc[model] = {"failed": entry}
        lines.append(f"\nFailed, not in the table: {MODEL_LABELS.get(model, model)} "
                     f"({entry['error']}: {entry['reason']})")
    return "\n".join(lines) + "\n", doc


def interval_text(interval: dict[str, Any] | None) -> str:
    """'1.42 SD (≈ 0.0123)' for an interval normalized by the target's SD, '0.00412 + 0.153·abs(p)' for one
    whose spread grows with the prediction p (no '|': a table's cell), '0.0123' for one half-width."""
    if not interval:
        return "n/a"
    if interval.get("scale") == "target_sd":
        return f"{interval['half_width_sd']:.2f} SD (≈ {interval['half_width']:.3g})"
    if interval.get("scale") == "prediction":
        a, b = (interval["half_width_scaled"] * c for c in interval["spread"])
        return f"{a:.3g} + {b:.3g}·abs(p)"
    return f"{interval['half_width']:.3g}"


#: Fig. 4's lowest R² on scale: below it a box says nothing the others need, and would squash them
R2_FLOOR = -1.0


def fold_scores(folds: dict[str, Any], outputs: Sequence[str]) -> dict[str, dict[str, list[float]]]:
    """``{model: {output: [fold test R², ...]}}`` from per-fold records (``fold_scores.json`` / a result's
    ``folds``: ``[{"test": {output: {"r2": ...}}}, ...]``); non-finite scores dropped."""
    out: dict[str, dict[str, list[float]]] = {}
    for model, records in folds.items():
        for o in outputs:
            values = [((f.get("test") or {}).get(o) or {}).get("r2") for f in records or [] if isinstance(f, dict)]
            values = [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
            if values:
                out.setdefault(model, {})[o] = values
    return out


def fold_figure(scores: dict[str, dict[str, list[float]]], outputs: Sequence[str],
                failed: dict[tuple[str, str], str] | None = None, floor: float = R2_FLOOR) -> tuple[Any, list[str]]:
    """Fig. 4: box plots of the fold test R² per model, one panel per output (matplotlib figure, Agg). A model in
    ``failed`` (``(model, output) -> why``) is drawn red and named with its verdict; the axis never goes below
    ``floor`` (or the lowest score above it), and each model cut off there is annotated on the panel ("Gertler–Hagen:
    fold R² down to −27, off scale"). Returns the figure and those annotations."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    failed = failed or {}
    fig, axes = plt.subplots(1, len(outputs), figsize=(4.2 * len(outputs), 4.4), squeeze=False)
    models = [m for m in scores if any(scores[m].get(o) for o in outputs)]
    off_scale: list[str] = []
    for ax, out in zip(axes[0], outputs, strict=True):
        shown = [m for m in models if scores[m].get(out)]
        data = [scores[m][out] for m in shown]
        if not data:
            ax.set_visible(False)
            continue
        low = min(min(d) for d in data)
        bottom = max(low, floor)
        top = max(1.0, max(max(d) for d in data))
        pad = 0.05 * (top - bottom or 1.0)
        boxes = ax.boxplot(data, whis=(0, 100), patch_artist=True)
        cut = []
        for i, (m, d) in enumerate(zip(shown, data, strict=True)):
            bad = (m, out) in failed
            boxes["boxes"][i].set_facecolor("#f4c7c3" if bad else "#dbe7f3")
            boxes["boxes"][i].set_edgecolor("#a40000" if bad else "#1f4e79")
            if min(d) < bottom - 1e-12:
                note = f"{label(m)}: fold R² down to {min(d):.3g}, off scale"
                cut.append(note)
                off_scale.append(f"{note} ({axis_label(out)})")
                ax.annotate("", xy=(i + 1, bottom - pad * 0.6), xytext=(i + 1, bottom + 2.5 * pad),
                            arrowprops={"arrowstyle": "->", "color": "#a40000"})
        names = [label(m) + ("\n(failed: train R² < 0)" if (m, out) in failed else "") for m in shown]
        ax.set_xticks(range(1, len(shown) + 1), names, rotation=35, ha="right", fontsize=8)
        for tick, m in zip(ax.get_xticklabels(), shown, strict=True):
            if (m, out) in failed:
                tick.set_color("#a40000")
        ax.set_ylim(bottom - pad, top + pad)
        if cut:
            ax.text(0.02, 0.02, "\n".join(cut), transform=ax.transAxes, fontsize=7, color="#a40000", va="bottom")
        ax.set_title(axis_label(out))
        ax.set_ylabel("fold test R² [-]")
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return fig, off_scale
