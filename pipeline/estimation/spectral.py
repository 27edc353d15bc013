"""Targets against what the vehicle can do: each target's spectrum against its inputs' (the check) and a band
limit the user switches on from it (the remedy).

- :func:`check_targets` (the derive stage, per trial): per measured DOF, the input band (the widest frequency below
  which the DOF's generalized force or an actuator signal puts all but :data:`INPUT_SHARE` of its variance; the
  acceleration M^-1 (tau - g - C nu - d) follows the inputs, their products reach :data:`BAND_FACTOR` times the
  band), the share of each target's variance above that (the acceleration u̇ ... and the damping target
  d_u ...), and the narrow-band peaks there (frequency, share of the target's variance). A target gets a warning
  with the remedy where the share above the band that no input explains (by coherence: the fast response to a
  thrust step is explained, noise and vibration are not) exceeds :data:`SHARE_LIMIT`, or a peak there exceeds
  :data:`PEAK_LIMIT`: a carriage or shaft vibration the smoother passed on, which no model can learn from the
  inputs.
- :func:`band_limit` (the differentiate stage, when ``notch_hz`` or ``max_hz`` is set): zero-phase notches and a
  low-pass applied per segment to the velocities and accelerations on the grid, after the method. On the grid, not
  on the sensors' own stamps: the Kalman smoother reads each sensor at its own, uneven stamps with gaps, where a
  digital filter has no uniform series to run on; the grid is uniform within a segment for every method, and an
  LTI filter commutes with the derivative, so the filtered velocity and acceleration stay each other's pair.

Spectra are Welch averages (Hann windows of :data:`WINDOW_S`, half overlap, mean removed) over every segment long
enough, weighted by their windows: deterministic, numpy only.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline import layout
from pipeline.config.params import DifferentiateParams
from pipeline.errors import ConfigError, SchemaError
from pipeline.vocabulary import ACCELERATION, DAMPING_COLUMNS, DOFS, SMOOTH, TAU_COLUMNS, VELOCITY

log = logging.getLogger(__name__)

__all__ = ["BAND_FACTOR", "INPUT_SHARE", "PEAK_LIMIT", "SHARE_LIMIT", "band_limit", "check_targets",
           "remove_disturbances", "report_path", "spectrum"]

#: The input band: below it the DOF's inputs put all but this share of their variance
INPUT_SHARE = 0.02
#: The check looks above this multiple of the widest input band: products of inputs and motion (v r, delta^2,
#: n|n|) reach twice an input's frequencies (a zig-zag's surge deceleration oscillates at twice the rudder's)
BAND_FACTOR = 2.0
#: A target is flagged where more than this share of its variance lies above the band unexplained by the inputs
#: (coherence), or where a narrow-band peak there holds more than PEAK_LIMIT of it. Chosen on validation seeds,
#: with what clean and ringing trials give, in docs/estimation.md ("Targets against what the actuators can do")
SHARE_LIMIT = 0.1
PEAK_LIMIT = 0.05
#: A narrow-band peak: a local maximum this many times the median spectrum around it (within NEIGHBOUR_HZ) ...
PEAK_RATIO = 10.0
NEIGHBOUR_HZ = 0.5
#: ... holding at least this share of the target's variance within PEAK_HALF_WIDTH_HZ of it
PEAK_MIN_SHARE = 0.02
PEAK_HALF_WIDTH_HZ = 0.15
#: Welch window (s): 0.05-Hz bins; shorter segments are skipped unless none is long enough
WINDOW_S = 20.0


def report_path(root: Path, trial: str) -> Path:
    """The derive stage's spectral check of one trial, beside its derived table."""
    return Path(root) / layout.DERIVED / f"{trial}.spectra.json"


def _segments(frame: pd.DataFrame) -> tuple[list[np.ndarray], float]:
    if "t_ns" not in frame.columns or "segment" not in frame.columns:
        raise SchemaError("the table needs t_ns and segment columns for its spectra", field="t_ns")
    seg = frame["segment"].to_numpy()
    t = frame["t_ns"].to_numpy(dtype=np.int64)
    rows = [np.flatnonzero(seg == s) for s in np.unique(seg[seg >= 0])]
    steps = np.concatenate([np.diff(t[r]) for r in rows]) if rows else np.zeros(0, dtype=np.int64)
    if steps.size == 0:
        raise SchemaError("no segment with two or more samples for a spectrum", field="segment")
    return rows, float(np.median(steps)) / 1e9


def _windows(x: np.ndarray, rows: list[np.ndarray], dt_s: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The Hann-windowed FFTs of ``x`` (one row per window, every segment long enough; windows overlap by half),
    their frequencies (Hz) and the scale that makes mean |X|^2 a one-sided PSD per Hz (bins 1..-2 doubled by the
    caller). One FFT call per segment, over all its windows."""
    nper = min(int(round(WINDOW_S / dt_s)), max(len(r) for r in rows))
    window = np.hanning(nper)
    step = max(nper // 2, 1)
    pieces = []
    for r in rows:
        if len(r) < nper:
            continue
        frames = np.lib.stride_tricks.sliding_window_view(x[r], nper)[::step]
        pieces.append(np.fft.rfft((frames - frames.mean(axis=1, keepdims=True)) * window, axis=1))
    spec = np.concatenate(pieces) if pieces else np.zeros((0, nper // 2 + 1), dtype=complex)
    return spec, np.fft.rfftfreq(nper, dt_s), 1.0 / (np.sum(window**2) / dt_s)


def _psd(spec: np.ndarray, scale: float) -> np.ndarray:
    psd = np.mean(np.abs(spec) ** 2, axis=0) * scale
    psd[1:-1] *= 2  # one-sided
    return psd


def spectrum(x: np.ndarray, rows: list[np.ndarray], dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Welch power spectral density of ``x`` over the segments ``rows`` (frequencies in Hz, PSD per Hz)."""
    spec, freq, scale = _windows(x, rows, dt_s)
    return freq, _psd(spec, scale)


def _coherence(sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
    pxx, pyy = np.mean(np.abs(sx) ** 2, axis=0), np.mean(np.abs(sy) ** 2, axis=0)
    pxy = np.abs(np.mean(sx * np.conj(sy), axis=0)) ** 2
    den = pxx * pyy
    return np.divide(pxy, den, out=np.zeros_like(den), where=den > 0)


def coherence(x: np.ndarray, y: np.ndarray, rows: list[np.ndarray], dt_s: float) -> np.ndarray:
    """Welch magnitude-squared coherence of ``x`` and ``y`` per frequency bin: the share of x's power there that a
    linear filter of y explains (0 where either has none)."""
    return _coherence(_windows(x, rows, dt_s)[0], _windows(y, rows, dt_s)[0])


def _band(freq: np.ndarray, psd: np.ndarray) -> float:
    """The lowest frequency below which ``psd`` holds all but INPUT_SHARE of its variance (DC excluded)."""
    power = psd[1:]
    cum = np.cumsum(power) / power.sum()
    return float(freq[1:][np.searchsorted(cum, 1.0 - INPUT_SHARE)])


def _share_above(freq: np.ndarray, psd: np.ndarray, f_hz: float) -> float:
    total = psd[1:].sum()
    return float(psd[1:][freq[1:] > f_hz].sum() / total) if total > 0 else 0.0


def _peaks(freq: np.ndarray, psd: np.ndarray, above_hz: float) -> list[dict[str, float]]:
    """Narrow-band peaks above ``above_hz``: frequency (parabolic on the log spectrum) and share of the variance
    over the background, largest share first."""
    df = freq[1] - freq[0]
    total = psd[1:].sum()
    if total <= 0:
        return []
    near, half = max(int(NEIGHBOUR_HZ / df), 3), max(int(round(PEAK_HALF_WIDTH_HZ / df)), 1)
    log_psd = np.log(np.maximum(psd, np.finfo(float).tiny))
    out = []
    for k in range(2, psd.size - 1):
        if freq[k] <= above_hz or not (psd[k] > psd[k - 1] and psd[k] >= psd[k + 1]):
            continue
        around = np.r_[psd[max(k - near, 1):max(k - half, 1)], psd[k + half + 1:k + near + 1]]
        background = float(np.median(around)) if around.size else 0.0
        if psd[k] < PEAK_RATIO * background:
            continue
        lobe = psd[max(k - half, 1):k + half + 1]
        share = float((lobe.sum() - background * lobe.size) / total)
        if share < PEAK_MIN_SHARE:
            continue
        a, b, c = log_psd[k - 1], log_psd[k], log_psd[k + 1]
        offset = 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else 0.0
        out.append({"frequency_hz": float(freq[k] + offset * df), "share": share})
    return sorted(out, key=lambda p: -p["share"])[:3]


def _label(column: str) -> str:
    for dof in DOFS:
        if column == ACCELERATION[DOFS.index(dof)]:
            return f"{dof}\u0307"
        if column == DAMPING_COLUMNS[dof]:
            return f"damping target d_{dof}"
    return column


def _low_pass_hz(band_hz: float, peaks: list[dict[str, float]]) -> float | None:
    """A low-pass between the band and the lowest peak: 1.25 times the band, in 0.1-Hz steps up; None where that
    does not lie below 0.8 times the lowest peak."""
    max_hz = math.ceil(12.5 * band_hz - 1e-9) / 10
    return max_hz if not peaks or max_hz < 0.8 * min(p["frequency_hz"] for p in peaks) else None


def _remedy(band_hz: float, peaks: list[dict[str, float]]) -> str:
    """The params keys that would remove what lies above the band: notches at the peaks, or a low-pass between
    the band and the lowest peak."""
    max_hz = _low_pass_hz(band_hz, peaks)
    if peaks:
        notches = ", ".join(f"{p['frequency_hz']:.2f}" for p in sorted(peaks, key=lambda p: p["frequency_hz"]))
        advice = f"consider `differentiate.notch_hz: [{notches}]`"
        return advice + (f" or `differentiate.max_hz: {max_hz:g}`" if max_hz is not None else "")
    return f"consider `differentiate.max_hz: {max_hz:g}` (or a smoother method)"


def check_targets(derived: pd.DataFrame, trial: str, actuators: list[str] | None = None, *,
                  targets: str = "all", log_warnings: bool = True) -> dict[str, Any]:
    """Per measured DOF, the band of its inputs and each target's share of variance above :data:`BAND_FACTOR` times
    it, and narrow-band peaks there; ``warnings``: one sentence per flagged target, with the remedy. The inputs of
    a DOF are its generalized force ``tau_<dof>`` and every column of ``actuators`` present (thrusts, actuator
    signals: through the coupling any actuator moves every DOF; a rudder the thrust map does not see), the widest
    band of them. ``targets="accelerations"``: the accelerations alone (no damping target, no warning logged
    unless ``log_warnings``)."""
    rows, dt_s = _segments(derived)
    windows: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
    out: dict[str, Any] = {"trial": trial, "grid_step_s": dt_s, "input_share": INPUT_SHARE,
                           "share_limit": SHARE_LIMIT, "peak_limit": PEAK_LIMIT, "dofs": {}, "warnings": []}
    for dof, acc in zip(DOFS, ACCELERATION, strict=True):
        if acc not in derived.columns or not np.ptp(derived[acc].to_numpy(dtype=float)) > 0:
            continue  # a DOF without a sensor: 0 throughout
        names = [c for c in dict.fromkeys([TAU_COLUMNS[dof], *(actuators or [])])
                 if c in derived.columns and np.ptp(derived[c].to_numpy(dtype=float)) > 0]
        if not names:
            continue
        for name in names:  # each input's windows once per trial: every DOF shares the actuators
            if name not in windows:
                windows[name] = _windows(derived[name].to_numpy(dtype=float), rows, dt_s)
        bands = []
        for name in names:
            spec, freq, scale = windows[name]
            psd = _psd(spec, scale)
            bands.append((_band(freq, psd), name, psd))
        widest, _, psd = max(bands, key=lambda b: b[0])
        band_hz = BAND_FACTOR * widest
        entry: dict[str, Any] = {"inputs": names, "input_band_hz": widest, "band_hz": band_hz,
                                 "input_share_above": _share_above(freq, psd, band_hz), "targets": {}}
        for col in (acc, DAMPING_COLUMNS[dof]) if targets == "all" else (acc,):
            if col not in derived.columns:
                continue
            spec, freq, scale = _windows(derived[col].to_numpy(dtype=float), rows, dt_s)
            psd = _psd(spec, scale)
            explained = np.max([_coherence(spec, windows[name][0]) for name in names], axis=0)
            share = _share_above(freq, psd, band_hz)
            above = freq > band_hz  # the share of the target's whole variance above the band that no input explains
            unexplained = float((psd * (1.0 - explained))[above].sum() / psd[1:].sum()) if psd[1:].sum() > 0 else 0.0
            peaks = _peaks(freq, psd, band_hz)
            flagged = unexplained > SHARE_LIMIT or bool(peaks and peaks[0]["share"] > PEAK_LIMIT)
            entry["targets"][col] = {"share_above_band": share, "unexplained_above_band": unexplained,
                                     "peaks": peaks, "flagged": flagged}
            if flagged:
                what = (f": a narrow-band disturbance at {peaks[0]['frequency_hz']:.2f} Hz "
                        f"({100 * peaks[0]['share']:.0f} % of its variance)" if peaks else "")
                text = (f"{trial}: {_label(col)} carries {100 * share:.0f} % of its variance above {band_hz:.2g} Hz "
                        f"where the actuators put {100 * entry['input_share_above']:.0f} % ({100 * unexplained:.0f} "
                        f"% unexplained by them){what}; {_remedy(band_hz, peaks)}")
                out["warnings"].append({"target": col, "share_above_band": share,
                                        "unexplained_above_band": unexplained, "band_hz": band_hz,
                                        "peak_hz": peaks[0]["frequency_hz"] if peaks else None, "text": text})
                if log_warnings:
                    log.warning("%s", text)
        out["dofs"][dof] = entry
    return out


def _sos(params: DifferentiateParams, dt_s: float) -> tuple[np.ndarray, int]:
    """The second-order sections of the notches and the low-pass, and the padding (3 time constants)."""
    from scipy import signal  # only for a run that asks for a band limit

    fs = 1.0 / dt_s
    sections, tau_s = [], 0.0
    for f in params.notch_hz:
        if not 0 < f + params.notch_width_hz / 2 < fs / 2:
            raise ConfigError(f"differentiate.notch_hz: {f:g} Hz (width {params.notch_width_hz:g} Hz) is not below "
                              f"the grid's Nyquist frequency {fs / 2:g} Hz", field="notch_hz")
        b, a = signal.iirnotch(f, f / params.notch_width_hz, fs=fs)
        sections.append(signal.tf2sos(b, a))
        tau_s = max(tau_s, 1.0 / (np.pi * params.notch_width_hz))
    if params.max_hz is not None:
        if params.max_hz >= fs / 2:
            raise ConfigError(f"differentiate.max_hz: {params.max_hz:g} Hz is not below the grid's Nyquist frequency "
                              f"{fs / 2:g} Hz", field="max_hz")
        sections.append(signal.butter(4, params.max_hz, fs=fs, output="sos"))
        tau_s = max(tau_s, 1.0 / params.max_hz)
    return np.vstack(sections), int(math.ceil(3 * tau_s / dt_s))


def band_limit(kin: pd.DataFrame, params: DifferentiateParams,
               dofs: tuple[str, ...] = DOFS) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The kinematics table with ``params.notch_hz`` notches and the ``params.max_hz`` low-pass applied, zero-phase,
    per segment, to each DOF's velocity, smoothed velocity and acceleration; and what was applied. Unchanged (and
    an empty report) when neither is set. ``dofs``: only these DOFs' columns. SD columns are kept: filtering
    removes variance, so they stay an upper bound."""
    if not params.notch_hz and params.max_hz is None:
        return kin, {}
    from scipy import signal

    rows, dt_s = _segments(kin)
    sos, pad = _sos(params, dt_s)
    out = kin.copy()
    columns = [c for j, dof in enumerate(DOFS) if dof in dofs
               for c in (VELOCITY[j], SMOOTH[j], ACCELERATION[j]) if c in out.columns]
    for col in columns:
        x = out[col].to_numpy(dtype=float).copy()
        for r in rows:
            if len(r) > 3:
                x[r] = signal.sosfiltfilt(sos, x[r], padtype="odd", padlen=min(pad, len(r) - 1))
        out[col] = x
    return out, {"notch_hz": list(params.notch_hz), "notch_width_hz": params.notch_width_hz,
                 "max_hz": params.max_hz, "columns": columns}


def remove_disturbances(kin: pd.DataFrame, params: DifferentiateParams,
                        actuators: list[str]) -> tuple[pd.DataFrame, list[dict[str, Any]]]:
    """The kinematics table with each narrow-band disturbance the check finds in an acceleration removed from that
    DOF's velocity, smoothed velocity and acceleration (``differentiate.disturbances: remove``, the default); and
    one entry per DOF treated. A DOF is treated where its acceleration is flagged against ``actuators`` and holds
    a peak above the band: by the check's low-pass (1.25 times the band) where it lies below the lowest peak, else
    by notches at the peaks (``notch_width_hz`` wide). The low-pass first: the smoother fitted its process noise
    to the disturbance too, so the target also carries broadband noise above the band that a notch leaves."""
    try:
        rep = check_targets(kin, "", actuators, targets="accelerations", log_warnings=False)
    except SchemaError:  # no segment long enough for a spectrum: nothing to find
        return kin, []
    out, removed = kin, []
    for dof, entry in rep["dofs"].items():
        acc = ACCELERATION[DOFS.index(dof)]
        found = entry["targets"][acc]
        if not (found["flagged"] and found["peaks"]):
            continue
        max_hz = _low_pass_hz(entry["band_hz"], found["peaks"])
        notches = [] if max_hz is not None else sorted(round(p["frequency_hz"], 2) for p in found["peaks"])
        step = params.model_copy(update={"notch_hz": notches, "max_hz": max_hz})
        out, applied = band_limit(out, step, dofs=(dof,))
        peak = found["peaks"][0]
        how = f"a {max_hz:g}-Hz low-pass" if max_hz is not None else f"notches at {notches} Hz"
        removed.append({"dof": dof, "target": acc, "frequency_hz": peak["frequency_hz"], "share": peak["share"],
                        "band_hz": entry["band_hz"], "max_hz": max_hz, "notch_hz": notches,
                        "columns": applied["columns"],
                        "text": (f"{_label(acc)} carried a narrow-band disturbance at {peak['frequency_hz']:.2f} Hz "
                                 f"({100 * peak['share']:.0f} % of its variance) that no actuator explains: "
                                 f"removed from {dof} by {how} (`differentiate.disturbances: keep` leaves it)")})
    return out, removed
