"""Put the streams of one trial on one uniform time grid, with a validity mask per signal and segment ids.

``synchronize(streams, vehicle, params)`` is pure: streams in (``t_ns`` + float64 signal columns, the
signals contract of ``docs/contracts.md``), one DataFrame out (the synced contract).

- **Grid**: every ``1/rate_hz`` seconds (period rounded to whole nanoseconds), at integer multiples of the
  period (so the grid does not depend on which stream starts first), over the overlap of the streams that
  carry a required signal (:func:`required_signals`). Clock offsets were applied at ingest; none here.
- **Interpolation** per signal: ``linear`` (measured states, the default), ``zoh`` (zero-order hold:
  ``*_rpm`` commands and thrusters' PWM, which the ESCs hold until the next message: interpolating across a step
  would invent a PWM never sent), ``nearest`` (``*_flag``); ``params.interpolation`` overrides per signal. Quaternions
  (``<name>_quat_w/_x/_y/_z``) are made sign-continuous, then normalized-lerped (nlerp).
- **Gaps**: a grid sample is valid only if the samples it is computed from are valid and no further apart
  than ``max_gap_s[signal]`` (``max_gap_s['default']`` for the rest). Otherwise it is NaN with
  ``<signal>__valid`` False: nothing is made up inside a gap or beyond either end of a stream. A NaN source
  sample counts as an invalid sample.
- **DVL**: a source sample with the bottom-lock flag 0 or (``zero_is_invalid``) an exact zero vector is an
  invalid sample; grid samples whose nearest flag sample is 0 are invalid too.
- **Duplicate stamps**: samples of one stream that share a time stamp are merged into one before anything
  else, each signal averaged over the finite values (``*_flag`` signals take the minimum, so one unlocked DVL
  sample makes the merged one unlocked; quaternions are sign-aligned first); nothing is dropped silently: the
  count is logged as a warning and left in ``frame.attrs["duplicate_stamps"]``.
- **Optional streams**: the signals of a stream marked ``optional`` in the vehicle config that this trial lacks
  (ingest listed it under ``absent_streams``) become columns of NaN with ``<signal>__valid`` False, so that later
  stages see them as invalid, not as unknown columns; logged as a warning and listed in
  ``frame.attrs["absent_signals"]``. A required signal in such a stream raises SchemaError naming both.
- **Segments**: ``segment`` (int32) numbers the contiguous runs where every required signal is valid, in
  time order from 0; runs shorter than ``min_segment_s`` (counted as samples x period) get -1.

Pandas' ``merge_asof`` is not used: its tolerance drops rows silently and it cannot interpolate.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pyarrow as pa

from pipeline.config.params import SyncParams
from pipeline.config.vehicle import Vehicle
from pipeline.errors import ConfigError, SchemaError, SyncError
from pipeline.stamps import fmt_ns

log = logging.getLogger(__name__)

QUAT_PARTS = ("w", "x", "y", "z")
VALID_SUFFIX = "__valid"
DEFAULT_MAX_GAP_S = 0.5
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class _Signal:
    name: str  # config signal name (a quaternion: "ahrs_quat")
    stream: str
    columns: tuple[str, ...]  # one column, or the four quaternion columns


def quat_columns(signal: str) -> list[str]:
    """The four columns of a quaternion signal, w first."""
    return [f"{signal}_{p}" for p in QUAT_PARTS]


def valid_column(signal: str) -> str:
    return signal + VALID_SUFFIX


def required_signals(vehicle: Vehicle) -> list[str]:
    """Signals every later stage needs: velocity, attitude (where configured: without it the vehicle is level),
    configured rates, actuators (thruster inputs, control surface angles)."""
    sensors = vehicle.sensors
    names: list[str] = list(sensors.linear_velocity().velocity)
    att = sensors.attitude
    if att is None:
        pass
    elif att.quaternion is not None:
        names.append(att.quaternion)
    else:
        names += [s for s in (att.roll, att.pitch, att.yaw) if s is not None]
    names += [s for s in (sensors.rates.p, sensors.rates.q, sensors.rates.r) if s is not None]
    names += vehicle.actuator_signals()
    return list(dict.fromkeys(names))


def default_kind(signal: str) -> str:
    if signal.endswith("_rpm"):
        return "zoh"
    if signal.endswith("_flag"):
        return "nearest"
    return "linear"


def _as_arrays(stream: str, table: pd.DataFrame | pa.Table) -> dict[str, np.ndarray]:
    """Column arrays of a stream, sorted by time (stable); t_ns as int64, the rest float64."""
    if isinstance(table, pa.Table):
        cols = {name: table.column(name).to_numpy() for name in table.column_names}
    else:
        cols = {name: table[name].to_numpy() for name in table.columns}
    if "t_ns" not in cols:
        raise SchemaError(f"stream {stream!r} has no t_ns column; found {sorted(cols)}", field="t_ns")
    t = np.asarray(cols.pop("t_ns"))
    if not np.issubdtype(t.dtype, np.integer):
        raise SchemaError(f"stream {stream!r}: t_ns must be int64 nanoseconds, found {t.dtype}", field="t_ns")
    order = np.argsort(t, kind="stable")
    out = {"t_ns": t.astype(np.int64)[order]}
    for name, values in cols.items():
        out[name] = np.asarray(values, dtype=np.float64)[order]
    return out


def merge_duplicates(cols: dict[str, np.ndarray],
                     quats: list[tuple[str, ...]] = ()) -> tuple[dict[str, np.ndarray], int]:
    """Merge the samples of one time-sorted stream that share a stamp; returns (columns, samples merged away).

    Per column, the mean of the finite values of each run of equal stamps (NaN if none is finite; a run whose
    values are all equal keeps that value exactly); ``*_flag`` columns take the minimum. The columns of each
    quaternion in ``quats`` (w, x, y, z) are flipped to the sign of the run's first sample before averaging
    (q and -q are one attitude). Without duplicates the input is returned as is.
    """
    t = cols["t_ns"]
    if t.size < 2:
        return cols, 0
    new_run = np.concatenate([[True], t[1:] != t[:-1]])
    starts = np.flatnonzero(new_run)
    merged = int(t.size - starts.size)
    if merged == 0:
        return cols, 0
    run_of = np.cumsum(new_run) - 1
    cols = dict(cols)
    for group in quats:
        q = np.stack([cols[c] for c in group], axis=1)
        dots = np.einsum("ij,ij->i", q, q[starts][run_of])
        sign = np.where(np.nan_to_num(dots) < 0, -1.0, 1.0)
        for j, c in enumerate(group):
            cols[c] = q[:, j] * sign
    out = {"t_ns": t[starts]}
    for name, x in cols.items():
        if name == "t_ns":
            continue
        finite = np.isfinite(x)
        n = np.add.reduceat(finite.astype(np.int64), starts)
        if name.endswith("_flag"):
            value = np.minimum.reduceat(np.where(finite, x, np.inf), starts)
        else:
            ref = np.maximum.reduceat(np.where(finite, x, -np.inf), starts)
            dev = np.add.reduceat(np.where(finite, x - ref[run_of], 0.0), starts)
            with np.errstate(invalid="ignore", divide="ignore"):
                value = ref + dev / n
        out[name] = np.where(n > 0, value, np.nan)
    return out, merged


def _columns_of(signal: str) -> list[str]:
    return quat_columns(signal) if signal.endswith("_quat") else [signal]


def absent_optional(vehicle: Vehicle, found: Mapping[str, object]) -> dict[str, str]:
    """Signals of the vehicle's optional streams that are not among ``found``: signal -> its stream."""
    return {signal: name for name, stream in vehicle.streams.items() if stream.optional
            for signal in stream.signals if signal not in found}


def _find_signals(arrays: dict[str, dict[str, np.ndarray]]) -> dict[str, _Signal]:
    signals: dict[str, _Signal] = {}
    for stream in sorted(arrays):
        names = [c for c in arrays[stream] if c != "t_ns"]
        taken: set[str] = set()
        for col in names:
            if col.endswith("_quat_w"):
                base = col[: -len("_w")]
                parts = quat_columns(base)
                if all(p in names for p in parts):
                    signals[base] = _Signal(base, stream, tuple(parts))
                    taken.update(parts)
        for col in names:
            if col not in taken:
                if col in signals:
                    raise SchemaError(f"signal {col!r} appears in streams {signals[col].stream!r} and {stream!r}",
                                      field=col)
                signals[col] = _Signal(col, stream, (col,))
    return signals


def resample(t_ns: np.ndarray, x: np.ndarray, ok: np.ndarray, grid_ns: np.ndarray, kind: str,
             max_gap_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Resample samples ``x`` (n,) or (n, k) at ``t_ns`` onto ``grid_ns``; returns (values, valid).

    A grid time equal to a sample time takes that sample. Between two samples ``a <= t < b``: linear uses both
    (valid if both are valid), zoh uses ``a``, nearest the closer one (ties: ``a``); each requires
    ``b - a <= max_gap_ns``. Before the first or after the last sample: invalid. Invalid grid samples are NaN.
    """
    n = len(t_ns)
    shape = (len(grid_ns),) + x.shape[1:]
    if n == 0:
        return np.full(shape, np.nan), np.zeros(len(grid_ns), dtype=bool)
    i = np.searchsorted(t_ns, grid_ns, side="right") - 1
    inside = i >= 0
    il = np.clip(i, 0, n - 1)
    ir = np.clip(i + 1, 0, n - 1)
    exact = inside & (t_ns[il] == grid_ns)
    bracket = inside & (i + 1 < n) & ~exact
    gap = t_ns[ir] - t_ns[il]
    bracket &= gap <= max_gap_ns
    if kind == "linear":
        span = np.where(bracket, gap, 1).astype(np.float64)
        w = np.where(bracket, (grid_ns - t_ns[il]).astype(np.float64) / span, 0.0)
        w = w.reshape((-1,) + (1,) * (x.ndim - 1))
        values = x[il] + w * (x[ir] - x[il])
        valid = (exact & ok[il]) | (bracket & ok[il] & ok[ir])
    elif kind == "zoh":
        values = x[il].copy()
        valid = (exact & ok[il]) | (bracket & ok[il])
    elif kind == "nearest":
        pick = np.where(grid_ns - t_ns[il] <= t_ns[ir] - grid_ns, il, ir)
        pick = np.where(exact, il, pick)
        values = x[pick].copy()
        valid = (exact & ok[il]) | (bracket & ok[pick])
    else:
        raise ValueError(f"unknown interpolation kind {kind!r}; expected linear, zoh or nearest")
    values = np.where(valid.reshape((-1,) + (1,) * (x.ndim - 1)), values, np.nan)
    return values, valid


def sign_continuous(q: np.ndarray) -> np.ndarray:
    """Flip quaternions (n, 4) so each has a non-negative dot product with the previous one (q ~ -q)."""
    q = q.copy()
    if len(q) < 2:
        return q
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    flips = np.concatenate([[False], np.nan_to_num(dots) < 0])
    sign = np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)
    return q * sign[:, None]


def grid_for(start_ns: int, end_ns: int, period_ns: int) -> np.ndarray:
    """Multiples of ``period_ns`` within [start_ns, end_ns]."""
    first = -(-start_ns // period_ns) * period_ns
    last = (end_ns // period_ns) * period_ns
    if last < first:
        return np.empty(0, dtype=np.int64)
    return np.arange(first, last + 1, period_ns, dtype=np.int64)


def segments(valid: np.ndarray, min_samples: int) -> np.ndarray:
    """int32 ids of the contiguous True runs of ``valid`` with at least ``min_samples`` samples; -1 elsewhere."""
    seg = np.full(len(valid), -1, dtype=np.int32)
    if len(valid) == 0:
        return seg
    v = valid.astype(np.int8)
    edges = np.diff(np.concatenate([[0], v, [0]]))
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    next_id = 0
    for a, b in zip(starts, stops, strict=True):
        if b - a >= max(min_samples, 1):
            seg[a:b] = next_id
            next_id += 1
    return seg


def _dvl_sample_ok(vehicle: Vehicle, signals: dict[str, _Signal],
                   arrays: dict[str, dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Per velocity signal, which of its source samples are usable (valid flag / bottom lock; for a DVL, not an
    exact zero)."""
    dvl = vehicle.sensors.linear_velocity()
    out: dict[str, np.ndarray] = {}
    streams = {signals[s].stream for s in dvl.velocity if s in signals}
    for stream in streams:
        cols = arrays[stream]
        mine = [s for s in dvl.velocity if s in signals and signals[s].stream == stream]
        ok = np.ones(len(cols["t_ns"]), dtype=bool)
        if dvl.valid is not None and dvl.valid in cols:
            ok &= np.nan_to_num(cols[dvl.valid], nan=0.0) != 0
        if dvl.zero_is_invalid:
            if len(mine) == len(dvl.velocity):
                ok &= ~np.all(np.stack([cols[s] for s in mine]) == 0.0, axis=0)
            else:
                log.warning("DVL velocity signals are split over streams; zero_is_invalid checked per stream "
                            "on the components found together")
                ok &= ~np.all(np.stack([cols[s] for s in mine]) == 0.0, axis=0)
        for s in mine:
            out[s] = ok
    return out


def _no_overlap_message(arrays: dict[str, dict[str, np.ndarray]], req_streams: list[str], start: int, end: int,
                        rate_hz: float, duplicates: dict[str, dict[str, int]]) -> str:
    """Which streams do not overlap, each with its time span, and where to look for the cause."""
    span = {s: (int(arrays[s]["t_ns"][0]), int(arrays[s]["t_ns"][-1])) for s in req_streams}
    apart = {s: [o for o in req_streams if o != s and (span[o][0] > span[s][1] or span[o][1] < span[s][0])]
             for s in req_streams}
    odd = [s for s in req_streams if len(apart[s]) > (len(req_streams) - 1) / 2] or [s for s in req_streams
                                                                                     if apart[s]]
    spans = []
    for s in req_streams:
        first, last = span[s]
        n = duplicates.get(s, {}).get("samples", len(arrays[s]["t_ns"]))
        same = f" (all {n} stamps equal)" if first == last and n > 1 else ""
        mark = ""
        if s in odd:
            mark = (" <- overlaps none of the others" if len(apart[s]) == len(req_streams) - 1
                    else f" <- no overlap with {apart[s]}")
        spans.append(f"{s!r}: {fmt_ns(first)} to {fmt_ns(last)}{same}{mark}")
    if start > end:
        what = f"latest start {fmt_ns(start)} is after earliest end {fmt_ns(end)}"
    else:
        what = f"the overlap {fmt_ns(start)} to {fmt_ns(end)} holds no {rate_hz:g} Hz grid point"
    return (f"the streams carrying required signals do not overlap in time ({what}); " + "; ".join(spans)
            + ". A stream at zero, at a constant or near 0 s while the others hold wall-clock time usually has "
            "zero or simulation-time header stamps: see 'stamp_warnings' in the trial's ingest_report.json, and "
            "set `clock: log` (or `time: {rate_hz: ...}`) for that stream, or fix its `offset_s`")


def check_params(vehicle: Vehicle, params: SyncParams) -> None:
    """Per-signal settings must name configured signals (a typo would silently fall back to the default)."""
    known = set(vehicle.signal_names())
    for key, mapping in (("interpolation", params.interpolation), ("max_gap_s", params.max_gap_s)):
        for name in mapping:
            if name != "default" and name not in known:
                raise ConfigError(f"sync.{key} names {name!r}, which is not a signal of vehicle "
                                  f"{vehicle.name!r}; known: {sorted(known)}", field=f"sync.{key}.{name}")


def synchronize(streams: Mapping[str, pd.DataFrame | pa.Table], vehicle: Vehicle,
                params: SyncParams) -> pd.DataFrame:
    """Resample the streams of one trial onto one grid; see the module docstring for the rules."""
    check_params(vehicle, params)
    arrays = {name: _as_arrays(name, table) for name, table in streams.items()}
    signals = _find_signals(arrays)
    duplicates: dict[str, dict[str, int]] = {}
    for stream in sorted(arrays):
        quats = [sig.columns for sig in signals.values() if sig.stream == stream and len(sig.columns) == 4]
        n_before = len(arrays[stream]["t_ns"])
        arrays[stream], merged = merge_duplicates(arrays[stream], quats)
        if merged:
            duplicates[stream] = {"samples": n_before, "merged_away": merged, "kept": n_before - merged}
            log.warning("stream %r: %d of %d samples share a time stamp with the one before; merged into %d "
                        "(each signal averaged); see the stamp warnings of the ingest report for the remedy",
                        stream, merged, n_before, n_before - merged)
    required = required_signals(vehicle)
    absent = absent_optional(vehicle, signals)
    missing = [s for s in required if s not in signals]
    if missing:
        optional = {s: absent[s] for s in missing if s in absent}
        why = (f"; stream(s) {sorted(set(optional.values()))} are optional and absent from this trial, but carry "
               f"the required signal(s) {sorted(optional)}" if optional else "")
        raise SchemaError(f"required signal(s) {missing} not in any stream{why}; found {sorted(signals)}",
                          field=missing[0])
    if absent:
        log.warning("optional stream(s) %s absent: signal(s) %s are NaN and invalid in this trial",
                    sorted(set(absent.values())), sorted(absent))
    req_streams = sorted({signals[s].stream for s in required})
    if any(len(arrays[s]["t_ns"]) == 0 for s in req_streams):
        empty = [s for s in req_streams if len(arrays[s]["t_ns"]) == 0]
        raise SyncError(f"stream(s) {empty} carry required signals but have no samples")
    start = max(int(arrays[s]["t_ns"][0]) for s in req_streams)
    end = min(int(arrays[s]["t_ns"][-1]) for s in req_streams)
    period_ns = int(round(NS_PER_S / params.rate_hz))
    grid = grid_for(start, end, period_ns)
    if len(grid) == 0:
        raise SyncError(_no_overlap_message(arrays, req_streams, start, end, params.rate_hz, duplicates))

    dvl_ok = _dvl_sample_ok(vehicle, signals, arrays)
    pwm = {t.pwm_signal for t in vehicle.thrusters if t.pwm_signal is not None}  # commands: held
    out: dict[str, np.ndarray] = {"t_ns": grid}
    valid: dict[str, np.ndarray] = {}
    for name, sig in signals.items():
        cols = arrays[sig.stream]
        t = cols["t_ns"]
        kind = params.interpolation.get(name, "zoh" if name in pwm else default_kind(name))
        gap_s = params.max_gap_s.get(name, params.max_gap_s.get("default", DEFAULT_MAX_GAP_S))
        gap_ns = int(round(gap_s * NS_PER_S))
        if len(sig.columns) == 4:
            q = np.stack([cols[c] for c in sig.columns], axis=1)
            ok = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(np.nan_to_num(q), axis=1) > 0)
            q[ok] = sign_continuous(q[ok])
            q[~ok] = np.nan
            values, v = resample(t, q, ok, grid, kind, gap_ns)
            values = values / np.linalg.norm(values, axis=1, keepdims=True)
            for j, c in enumerate(sig.columns):
                out[c] = values[:, j]
        else:
            x = cols[name]
            ok = np.isfinite(x) & dvl_ok.get(name, True)
            values, v = resample(t, x, ok, grid, kind, gap_ns)
            out[name] = values
        valid[name] = v

    dvl = vehicle.sensors.linear_velocity()
    if dvl.valid is not None and dvl.valid in signals:
        lock = valid[dvl.valid] & (np.nan_to_num(out[dvl.valid], nan=0.0) != 0)
        for s in dvl.velocity:
            valid[s] &= lock
            out[s] = np.where(valid[s], out[s], np.nan)

    if absent:  # an absent optional stream: its signals are there, invalid everywhere, in their usual place
        ghosts: dict[str, dict[str, np.ndarray]] = {}
        for name, stream in absent.items():
            ghost = ghosts.setdefault(stream, dict(arrays.get(stream, {"t_ns": grid[:0]})))
            for c in _columns_of(name):
                out[c] = ghost[c] = np.full(len(grid), np.nan)
            valid[name] = np.zeros(len(grid), dtype=bool)
        order = list(_find_signals({**arrays, **ghosts}))
        out = {"t_ns": out["t_ns"], **{c: out[c] for name in order for c in _columns_of(name)}}
        valid = {name: valid[name] for name in order}

    all_req = np.logical_and.reduce([valid[s] for s in required])
    min_samples = int(np.ceil(params.min_segment_s * params.rate_hz - 1e-9))
    seg = segments(all_req, min_samples)
    if not np.any(seg >= 0):
        raise SyncError(f"no stretch of at least {params.min_segment_s} s where all required signals "
                        f"{required} are valid ({int(all_req.sum())} of {len(grid)} grid samples valid)")
    frame = pd.DataFrame(out)
    for name in valid:
        frame[valid_column(name)] = valid[name]
    frame["segment"] = seg
    frame.attrs["duplicate_stamps"] = duplicates
    frame.attrs["absent_signals"] = absent
    log.debug("synced %d samples at %g Hz, %d segment(s)", len(grid), params.rate_hz, int(seg.max()) + 1)
    return frame
