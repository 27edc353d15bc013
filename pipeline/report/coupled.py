"""The coupled study's tables and figure (paper 000): Table II (chosen hyperparameters, stages.tune), Table III (CV
and final-check R² per model and output) and the Fig. 4-like box plot of the fold test R² (stages.train)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pipeline.units import axis_label

MODEL_LABELS = {"rbf_svr": "RBF-SVR", "two_weights_svr": "2-weights-SVR", "wdse_svr": "WDSE-SVR",
                "gertler_hagen": "Gertler-Hagen", "mcfarland_whitcomb": "McFarland-Whitcomb",
                "graybox": "Gray-box (MW + WDSE)", "graybox_gh": "Gray-box (GH + WDSE)"}


def table2(hyper: dict[str, dict[str, dict[str, Any]]], outputs: Sequence[str], inputs: Sequence[str]) -> str:
    """Table II-like markdown: chosen hyperparameters per model and output (gammas on standardized inputs)."""
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
    return "\n".join(lines) + "\n"


def table3(results: dict[str, Any], outputs: Sequence[str], failed: dict[str, dict[str, str]] | None = None
           ) -> tuple[str, dict[str, Any]]:
    """Table III-like markdown + JSON: CV R² (train/test mean, SD) per model and output, MAE, final check.
    The models in ``failed`` are named under the table (JSON: ``{model: {"failed": entry}}``)."""
    lines = ["| Model | Output | train R² mean | train R² SD | test R² mean | test R² SD | test MAE mean | "
             "final-check R² |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    doc: dict[str, Any] = {}
    for model, res in results.items():
        doc[model] = {"cv": res["summary"], "final": res["final"]}
        for out in outputs:
            s = res["summary"][out]
            final = f"{res['final'][out]['r2']:.3f}" if res["final"] else "n/a"
            lines.append(f"| {MODEL_LABELS.get(model, model)} | {out} | {s['train_r2']['mean']:.3f} | "
                         f"{s['train_r2']['sd']:.3f} | {s['test_r2']['mean']:.3f} | {s['test_r2']['sd']:.3f} | "
                         f"{s['test_mae']['mean']:.4g} | {final} |")
    for model, entry in (failed or {}).items():
        doc[model] = {"failed": entry}
        lines.append(f"\nFailed, not in the table: {MODEL_LABELS.get(model, model)} "
                     f"({entry['error']}: {entry['reason']})")
    return "\n".join(lines) + "\n", doc


def fold_boxplot(results: dict[str, Any], outputs: Sequence[str], target: Any) -> None:
    """Fig. 4-like box plots of the fold test R² per model, one panel per output (PNG, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.tableio import atomic_path

    fig, axes = plt.subplots(1, len(outputs), figsize=(4.2 * len(outputs), 4.0), squeeze=False)
    models = list(results)
    for ax, out in zip(axes[0], outputs, strict=True):
        data = [[f["test"][out]["r2"] for f in results[m]["folds"]] for m in models]
        ax.boxplot(data, whis=(0, 100))
        ax.set_xticks(range(1, len(models) + 1), [MODEL_LABELS.get(m, m) for m in models], rotation=35,
                      ha="right", fontsize=8)
        ax.set_title(axis_label(out))
        ax.set_ylabel("fold test R² [-]")
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
