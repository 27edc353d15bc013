"""The reader's name of a signal: ``udot_mps2`` -> "surge acceleration u̇ [m/s²]", built from the vocabulary's
column names (velocities, smoothed and measured velocities, accelerations, forces, damping, attitude), so that a
new column named there gets its label here; a column it does not name keeps its unit-aware axis label."""

from __future__ import annotations

from pipeline import vocabulary as V
from pipeline.units import axis_label

DOF_NAMES = {"u": "surge", "v": "sway", "w": "heave", "p": "roll", "q": "pitch", "r": "yaw"}


def _labels() -> dict[str, str]:
    out: dict[str, str] = {}
    for d in V.DOFS:
        name = DOF_NAMES[d]
        rate = "rate" if d in "pqr" else "velocity"
        out[V.velocity_column(d)] = f"{name} {rate} {axis_label(V.velocity_column(d))}"
        out[V.smooth_column(d)] = f"smoothed {name} {rate} {axis_label(V.velocity_column(d))}"
        out[V.meas_column(d)] = f"measured {name} {rate} {axis_label(V.velocity_column(d))}"
        out[V.acceleration_column(d)] = f"{name} acceleration {axis_label(V.acceleration_column(d))}"
        force = "moment" if d in "pqr" else "force"
        out[V.force_column(d, "tau")] = f"{name} {force} τ_{d} {axis_label(V.force_column(d, 'tau')).split(' ', 1)[1]}"
        out[V.force_column(d, "d")] = f"{name} damping {axis_label(V.force_column(d, 'd'))}"
    for column, (name, symbol) in zip(V.ATTITUDE, (("roll", "φ"), ("pitch", "θ"), ("yaw", "ψ")), strict=True):
        out[column] = f"{name} angle {symbol} [{axis_label(column).rsplit('[', 1)[1]}"
    return out


LABELS = _labels()


def signal_label(column: str) -> str:
    """"surge acceleration u̇ [m/s²]" for ``udot_mps2``; an unknown column by its axis label (``T_th2_N`` ->
    ``T_th2 [N]``)."""
    return LABELS.get(column) or axis_label(column)
