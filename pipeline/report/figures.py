"""Figures of the report, as PNG bytes (matplotlib, Agg backend, no timestamps in the file)."""

from __future__ import annotations

import io
import logging
from typing import Any

import numpy as np
import pandas as pd

from pipeline.report.names import signal_label
from pipeline.vocabulary import DOFS, force_column

log = logging.getLogger(__name__)

MAX_POINTS = 4000  # per signal line; longer trials are decimated for the picture only


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def png_bytes(fig: Any) -> bytes:
    """Render and close a figure; deterministic bytes (no Software/date metadata)."""
    plt = _pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Start/stop indices (stop exclusive) of the True runs of a boolean array."""
    if mask.size == 0:
        return []
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def signal_validity(frame: pd.DataFrame, trial: str, max_signals: int = 16) -> bytes | None:
    """Fig. 3-like: each synced signal over time, invalid stretches shaded red, segments shaded green."""
    if "t_ns" not in frame.columns or frame.empty:
        return None
    signals = [c for c in frame.columns if f"{c}__valid" in frame.columns][:max_signals]
    if not signals:
        signals = [c for c in frame.columns if c not in ("t_ns", "segment") and not c.endswith("__valid")
                   and pd.api.types.is_numeric_dtype(frame[c])][:max_signals]
    if not signals:
        return None
    plt = _pyplot()
    t = (frame["t_ns"].to_numpy(np.int64) - int(frame["t_ns"].iloc[0])) / 1e9
    step = max(1, len(t) // MAX_POINTS)
    fig, axes = plt.subplots(len(signals), 1, figsize=(10, 1.1 * len(signals) + 0.8), sharex=True, squeeze=False)
    segment = frame["segment"].to_numpy() if "segment" in frame.columns else None
    for ax, name in zip(axes[:, 0], signals, strict=True):
        y = frame[name].to_numpy(dtype=float)
        ax.plot(t[::step], y[::step], lw=0.7, color="#1f4e79")
        valid_col = f"{name}__valid"
        if valid_col in frame.columns:
            for a, b in _runs(~frame[valid_col].to_numpy(dtype=bool)):
                ax.axvspan(t[a], t[min(b, len(t) - 1)], color="#d62728", alpha=0.25, lw=0)
        if segment is not None:
            for a, b in _runs(segment >= 0):
                ax.axvspan(t[a], t[min(b, len(t) - 1)], color="#2ca02c", alpha=0.06, lw=0)
        ax.set_ylabel(signal_label(name).replace(" [", "\n["), rotation=0, ha="right", va="center", fontsize=7)
        ax.tick_params(labelsize=7)
    axes[-1, 0].set_xlabel("time since start [s]")
    axes[0, 0].set_title(f"{trial}: synced signals (red: invalid, green: usable segments)", fontsize=9)
    return png_bytes(fig)


def stream_rates(streams: dict[str, dict[str, Any]], trial: str) -> bytes | None:
    """Mean rate and largest gap per stream, from an ingest report."""
    names = [n for n, s in streams.items() if s.get("mean_rate_hz")]
    if not names:
        return None
    plt = _pyplot()
    rates = [float(streams[n]["mean_rate_hz"]) for n in names]
    gaps = [float(streams[n].get("largest_gap_s") or 0.0) for n in names]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 0.35 * len(names) + 1.2))
    a.barh(names, rates, color="#1f4e79")
    a.set_xscale("log")
    a.set_xlabel("mean rate [Hz]")
    b.barh(names, gaps, color="#d62728")
    b.set_xlabel("largest gap [s]")
    b.set_yticklabels([])
    for ax in (a, b):
        ax.tick_params(labelsize=7)
    fig.suptitle(f"{trial}: sensor rates and gaps", fontsize=9)
    return png_bytes(fig)


def validity_fractions(frame: pd.DataFrame) -> dict[str, float]:
    """Fraction of grid samples valid per signal, plus ``segment`` (fraction in a usable segment)."""
    out = {c[: -len("__valid")]: float(frame[c].mean()) for c in frame.columns if c.endswith("__valid")}
    if "segment" in frame.columns and len(frame):
        out["segment"] = float((frame["segment"].to_numpy() >= 0).mean())
    return out


def estimated_velocities(kin: pd.DataFrame, trial: str, window_s: float = 120.0) -> bytes | None:
    """Measured vs estimated u, v, r over the first ``window_s`` of a trial, the smoother's 2-sigma band
    shaded, and the stretches it bridged (no measurement: lost bottom lock) shaded orange."""
    dofs = [(d, u) for d, u in (("u", "mps"), ("v", "mps"), ("r", "radps")) if f"{d}_smooth_std_{u}" in kin.columns]
    if not dofs or kin.empty:
        return None
    plt = _pyplot()
    t_all = (kin["t_ns"].to_numpy(np.int64) - int(kin["t_ns"].iloc[0])) / 1e9
    keep = t_all <= window_s
    t = t_all[keep]
    fig, axes = plt.subplots(len(dofs), 1, figsize=(10, 2.0 * len(dofs) + 0.6), sharex=True, squeeze=False)
    for ax, (d, u) in zip(axes[:, 0], dofs, strict=True):
        est = kin[f"{d}_{u}"].to_numpy(float)[keep]
        sd = kin[f"{d}_smooth_std_{u}"].to_numpy(float)[keep]
        meas = kin[f"{d}_meas_{u}"].to_numpy(float)[keep] if f"{d}_meas_{u}" in kin.columns else None
        ax.fill_between(t, est - 2 * sd, est + 2 * sd, color="#1f77b4", alpha=0.25, lw=0, label="2σ band")
        if meas is not None:
            ax.plot(t, meas, ".", ms=2, color="#555555", label="measured (on the grid)")
            for a, b in _runs(~np.isfinite(meas)):
                ax.axvspan(t[a], t[min(b, len(t) - 1)], color="#ff7f0e", alpha=0.2, lw=0)
        ax.plot(t, est, lw=0.9, color="#1f4e79", label="estimate")
        ax.set_ylabel(signal_label(f"{d}_{u}").replace(" [", "\n["), fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7, loc="upper right", ncol=3)
    axes[-1, 0].set_xlabel("time since the first usable sample [s]")
    axes[0, 0].set_title(f"{trial}: measured vs estimated velocity (orange: bridged, no measurement)", fontsize=9)
    return png_bytes(fig)


def learning_curves(curves: dict[str, dict[str, dict[str, Any]]], units: dict[str, str]) -> bytes | None:
    """Paper 001's Fig. 2 with units: per DOF, validation (solid) and training (dashed) MAE of the damping
    against the number of training samples; ``curves[dof][model]`` holds ``train_sizes``, ``test_mae_mean``,
    ``train_mae_mean`` (the decoupled stage's ``learning_curve``)."""
    dofs = [d for d, per in curves.items() if any(c.get("train_sizes") for c in per.values())]
    if not dofs:
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(dofs), figsize=(4.2 * len(dofs), 3.4), squeeze=False)
    for ax, dof in zip(axes[0], dofs, strict=True):
        for i, (model, c) in enumerate(sorted(curves[dof].items())):
            sizes = c.get("train_sizes") or []
            color = f"C{i}"
            if c.get("test_mae_mean"):
                ax.plot(sizes, c["test_mae_mean"], "o-", color=color, ms=3, lw=1.2, label=f"{model}")
            if c.get("train_mae_mean"):
                ax.plot(sizes, c["train_mae_mean"], "--", color=color, lw=0.9)
        ax.set_yscale("log")
        ax.set_xlabel("training samples [rows]", fontsize=8)
        column = force_column(dof, "d") if dof in DOFS else f"d_{dof}"
        ax.set_ylabel(f"MAE of the {signal_label(column)}" if dof in DOFS else f"MAE of d_{dof} [{units.get(dof)}]",
                      fontsize=8)
        ax.set_title(f"DOF {dof}", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7, title="solid: validation, dashed: training", title_fontsize=7)
    fig.tight_layout()
    return png_bytes(fig)
