"""The decoupled damping study's table and figures (paper 001): Table I next to the CV scores, the learning curves
(Fig. 2), the fit / predict times (Fig. 3) and the learned damping curves, written by stages.decoupled."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.studies.decoupled import StudyResult, dof_columns, dof_data, net_buoyancy
from pipeline.units import axis_label


def _share(value: Any) -> str:
    return "–" if value is None else f"{value:.0%}"


def table_markdown(study: StudyResult) -> str:
    """Table I of the paper (search result) next to the CV scores on the train_test split, each model's 90 %
    prediction interval (± half-width) and its coverage on the unseen test trial(s) (the GP's 2σ band too)."""
    lines = ["| DOF | model | best params | search MAE | CV test MAE (sd) | CV test R² (sd) | CV train MAE | "
             "90 % interval ± | unseen: inside 90 % | unseen: inside GP 2σ |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in study.results:
        params = ", ".join(f"{k}: {v:g}" if isinstance(v, float) else f"{k}: {v}" for k, v in r.best_params.items())
        if r.model == "gp" and r.estimator is not None:
            scales = "/".join(f"{v:.3g}" for v in r.estimator.length_scale_)
            params = f"l-s: {scales} (standardized), n-l: {r.estimator.noise_std_:.3g}"
        c, half = r.cv, f"{r.interval['half_width']:.3g}" if r.interval else "–"
        if r.interval.get("scale") == "target_sd":  # a row's interval is +- q times its target's own SD
            half = f"{r.interval['half_width_sd']:.2f} SD (≈ {r.interval['half_width']:.3g})"
        lines.append(f"| {r.dof} | {r.model} | {params or 'N/A'} | {r.search_mae:.3f} | "
                     f"{c['test_mae_mean']:.3f} ({c['test_mae_sd']:.3f}) | {c['test_r2_mean']:.3f} "
                     f"({c['test_r2_sd']:.3f}) | {c['train_mae_mean']:.3f} | {half} | "
                     f"{_share(r.test.get('interval_coverage'))} | {_share(r.test.get('band_coverage'))} |")
    tested = sorted({t for r in study.results for t in r.test.get("trials", [])})
    lines.append("\n90 % interval: the prediction ± the conformal quantile of the blocked CV's out-of-fold "
                 "|residuals| (in units of each target's own SD where the store has it); GP 2σ: its predictive "
                 "SD with the learned noise and each target's own SD. "
                 + (f"Unseen: the share of the test trial(s) {', '.join(tested)} inside (85–95 % and 90–98 % "
                    "expected)." if tested else "No test trial in the store: coverage not measured."))
    for r in study.results:
        b = net_buoyancy(r, study.configured_net_buoyancy_N)
        if "B_minus_W_N" in b:
            sd = "" if b["sd_N"] is None else f" ± {b['sd_N']:.3f} (1 SD)"
            lines.append(f"\nHeave ({r.model} with a constant): B − W = {b['B_minus_W_N']:.3f} N{sd}: the vehicle "
                         f"config's {b['configured_N']:.3f} N plus the fitted constant {b['intercept_N']:.3f} N.")
    for f in study.failed:
        lines.append(f"\nFailed, not in the table: {f['dof']}/{f['model']} ({f['error']}: {f['reason']})")
    return "\n".join(lines) + "\n"


def _save(fig: Any, target: Path) -> Path:
    import matplotlib.pyplot as plt

    from pipeline.tableio import atomic_path

    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
    return Path(target)


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_learning_curves(study: StudyResult, target: Path) -> Path:
    """Fig. 2: training (dashed) and validation (solid) MAE vs training size, one panel per DOF."""
    plt = _plt()
    dofs = list(dict.fromkeys(r.dof for r in study.results))
    fig, axes = plt.subplots(1, len(dofs), figsize=(5 * len(dofs), 4), squeeze=False)
    for ax, dof in zip(axes[0], dofs, strict=True):
        for r in (r for r in study.results if r.dof == dof):
            lc = r.learning_curve
            line, = ax.plot(lc["train_sizes"], lc["test_mae_mean"], "o-", label=f"{r.model} validation")
            ax.plot(lc["train_sizes"], lc["train_mae_mean"], "--", color=line.get_color(), label=f"{r.model} training")
        ax.set_title(f"DOF {dof}")
        ax.set_xlabel("training samples [rows]")
        ax.set_ylabel(f"MAE of {axis_label(dof_columns(dof)[1])}")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=2)
    return _save(fig, target)


def plot_timings(timings: dict[str, Any], target: Path) -> Path:
    """Fig. 3: mean fit and predict time per fold, per (DOF, model), log scale."""
    plt = _plt()
    keys = list(timings)
    x = np.arange(len(keys))
    fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(keys)), 4))
    ax.bar(x - 0.2, [timings[k]["fit_time_s"] for k in keys], 0.4, label="fit")
    ax.bar(x + 0.2, [timings[k]["predict_time_s"] for k in keys], 0.4, label="predict")
    ax.set_xticks(x, keys, rotation=60, ha="right", fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("time per fold [s]")
    ax.legend()
    return _save(fig, target)


def plot_damping(study: StudyResult, data: pd.DataFrame, target: Path,
                 truth: Callable[[str, np.ndarray], np.ndarray] | None = None) -> Path:
    """The learned d_i(nu_i) over the data (and the truth where known), GP with its 2-sigma band."""
    plt = _plt()
    dofs = list(dict.fromkeys(r.dof for r in study.results))
    fig, axes = plt.subplots(1, len(dofs), figsize=(5 * len(dofs), 4), squeeze=False)
    for ax, dof in zip(axes[0], dofs, strict=True):
        X, y = dof_data(data, dof, 2000)
        ax.plot(X[:, 0], y, ".", ms=2, color="0.7", label="data")
        grid = np.linspace(X.min(), X.max(), 200)
        if truth is not None:
            ax.plot(grid, truth(dof, grid), "k--", lw=1.5, label="truth")
        for r in (r for r in study.results if r.dof == dof and r.estimator is not None):
            if r.model == "gp":
                mean, std = r.estimator.predict(grid[:, None], return_std=True)
                line, = ax.plot(grid, mean, label="gp")
                ax.fill_between(grid, mean - 2 * std, mean + 2 * std, color=line.get_color(), alpha=0.25, lw=0,
                                label="gp 2σ band")
            else:
                ax.plot(grid, r.estimator.predict(grid[:, None]), label=r.model)
        ax.set_xlabel(axis_label(dof_columns(dof)[0]))
        ax.set_ylabel(axis_label(dof_columns(dof)[1]))
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    return _save(fig, target)
