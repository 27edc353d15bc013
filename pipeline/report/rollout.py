"""The simulate stage's tables and figures: the bridging table as markdown, measured vs rolled-out velocity per
DOF (free runs, with the GP's band), and the position error at the end of DVL outages per outage length.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.report.names import signal_label
from pipeline.report.verdicts import band_verdict, label
from pipeline.vocabulary import VELOCITY_COLUMNS

if TYPE_CHECKING:
    from pipeline.rollout.runs import FreeRun


def bridging_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The bridging table as markdown (one row per outage length and model)."""
    def fmt(x: Any) -> str:
        return "-" if x is None else f"{x:.2f}"
    lines = ["| outage (s) | model | windows | diverged | mean error (m) | median (m) | max (m) | distance (m) |",
             "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['window_s']:g} | {r['model']} | {r['n_windows']} | {r['n_diverged']} | "
                     f"{fmt(r['mean_error_m'])} | {fmt(r['median_error_m'])} | {fmt(r['max_error_m'])} | "
                     f"{fmt(r['mean_distance_m'])} |")
    return "\n".join(lines) + "\n"


def plot_free_runs(runs: Sequence[FreeRun], target: Any, title: str = "") -> Any:
    """Fig. 4-like: measured vs predicted velocity per DOF; a diverged model ends with an x and its time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.tableio import atomic_path

    dofs = runs[0].dofs
    fig, axes = plt.subplots(len(dofs), 1, figsize=(10, 2.6 * len(dofs)), sharex=True, squeeze=False)
    for j, d in enumerate(dofs):
        ax = axes[j, 0]
        ax.plot(runs[0].t_s, runs[0].measured[:, j], color="k", lw=1.2, label="measured")
        for run in runs:
            r2 = (run.metrics.get(d) or {}).get("r2") if isinstance(run.metrics, dict) else None
            worse = isinstance(r2, float) and r2 < 0
            line, = ax.plot(run.t_s, run.predicted[:, j], lw=0.9, ls=":" if worse else "-",
                            label=label(run.name) + (f" (diverged at {run.diverged_at_s:.1f} s)"
                                                     if run.status == "diverged" else "")
                            + (f" (worse than the mean: R² {r2:.2g})" if worse else ""))
            if run.band is not None:  # drawn with its edges, so that it shows among the other models' lines
                cover = run.summary().get("band_coverage", {}).get(d)
                miss = band_verdict(cover)
                ax.fill_between(run.t_s, run.band[0][:, j], run.band[1][:, j], color=line.get_color(), alpha=0.3,
                                lw=0, label=f"{label(run.name)} 2σ band" + (
                                    f" ({miss}: covers {cover:.0%})" if miss else ""))
                for edge in run.band:
                    ax.plot(run.t_s, edge[:, j], color=line.get_color(), lw=0.6, ls="--")
            if run.status == "diverged" and run.diverged_at_s is not None:
                last = np.flatnonzero(np.isfinite(run.predicted[:, j]) & (run.t_s <= run.diverged_at_s))
                if last.size:
                    ax.plot(run.t_s[last[-1]], run.predicted[last[-1], j], "x", ms=9, color=line.get_color())
        ax.set_ylabel(signal_label(VELOCITY_COLUMNS[d]))
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=3, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
    return target


def bridging_figure(rows: Sequence[Mapping[str, Any]], failed: Mapping[str, str] | None = None) -> Any:
    """Mean position error at the end of the outage vs outage length, one line per model. A model that diverged
    in any window (its mean is over the windows it survived), or is in ``failed`` (model -> why), is drawn dotted
    with hollow markers and says so in the legend: it is never the line a reader takes for the best."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    failed = dict(failed or {})
    for r in rows:
        if (r.get("n_diverged") or 0) > 0:
            failed.setdefault(r["model"], f"diverged in {r['n_diverged']} of {r.get('n_windows')} windows")
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for name in dict.fromkeys(r["model"] for r in rows):
        pts = [(r["window_s"], r["mean_error_m"]) for r in rows if r["model"] == name and r["mean_error_m"] is not None]
        if pts:
            x, y = zip(*pts, strict=True)
            bad = name in failed
            ax.plot(x, y, marker="o", mfc="none" if bad else None, label=label(name) + (" (failed)" if bad else ""),
                    ls=":" if bad else "--" if name == "hold_last" else "-")  # why: in the report's verdicts
    ax.set_xlabel("DVL outage [s]")
    ax.set_ylabel("mean position error at the end [m]")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_bridging(rows: Sequence[Mapping[str, Any]], target: Any) -> Any:
    """:func:`bridging_figure` as the simulate stage writes it (PNG)."""
    import matplotlib.pyplot as plt

    from pipeline.tableio import atomic_path

    fig = bridging_figure(rows)
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
    return target
