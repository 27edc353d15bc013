"""Time-stamp sanity: what is wrong with a stream's stamps, in numbers, and the config change that fixes it.

:func:`check_stamps` is pure: the stamps a stream uses (in storage order, before its offset), the log time of
the same messages when there is one, and the stream's clock in; a :class:`StampCheck` out (counts for the
ingest report and a list of :class:`StampWarning`). Each warning says what was found (counts, example values)
and the remedy in config terms: ``clock: log`` (a topic whose header stamps are bad while its log time is
fine) or ``time: {rate_hz: R}`` (time rebuilt from the row index, uniformly sampled from the first stamp;
R estimated from the stamps when they allow it). The checks:

- ``zero``: header stamps equal to 0 (simulators that never fill the header);
- ``constant``: every stamp the same value (and not 0);
- ``far_from_log``: header stamps more than a day from the log time (simulation time, ~0-1000 s, in a log
  recorded with wall-clock time), by the median of |header - log|;
- ``duplicates``: equal consecutive stamps, at least :data:`DUPLICATE_WARN_FRACTION` of the intervals (sync
  averages the samples that share a stamp; a few are normal, many mean the stamps are coarser than the data);
- ``quantized``: distinct stamps typically further apart (median non-zero interval) than the mean interval
  (time written with 3 significant digits, or in whole seconds, for a 20 Hz stream);
- ``steps_back``: a stamp earlier than the one before it (ingest sorts by time; the order of the rows may be
  the true one).

:func:`check_rebuild` compares a time rebuilt at ``rate_hz`` with the stamps it replaces, end to end, within their
rounding (ingest refuses a text table's rebuild that drifts further; ``auvid inspect --vehicle`` warns).

:func:`time_stats` gives the span, mean rate, largest gap and steps back of a stamp array (the ingest report's
per-topic figures, and ``auvid inspect``'s).

Time stays int64 nanoseconds; seconds appear only in the messages.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np

NS_PER_S = 1_000_000_000
DAY_NS = 86_400 * NS_PER_S
EPOCH_LIKE_NS = 10 * 365 * DAY_NS  # stamps after 1980: wall-clock time; before: a relative or simulation clock
DUPLICATE_WARN_FRACTION = 0.01  # equal consecutive stamps, of the intervals, from which on a warning is logged
QUANTIZED_RATIO = 1.5  # median non-zero interval / mean interval from which the stamps count as quantized
N_EXAMPLES = 3


@dataclass(frozen=True)
class StampWarning:
    """One finding: ``check`` (its name), ``message`` (what was found), ``remedy`` (the config change)."""

    check: str
    message: str
    remedy: str
    count: int
    examples: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class StampCheck:
    """Counts of one stream's stamps and the warnings they raise (JSON-able through :meth:`as_dict`)."""

    checked: str  # which stamps: "header stamps", "log times", "time column 't'", ...
    count: int
    zeros: int
    distinct: int
    duplicates: int  # equal consecutive stamps
    duplicate_fraction: float  # of the n - 1 intervals
    median_step_s: float | None  # median of the non-zero intervals
    mean_interval_s: float | None
    steps_back: int
    header_minus_log_s: float | None  # median, header clock only
    warnings: list[StampWarning] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def fmt_ns(t_ns: int) -> str:
    """A stamp for humans: UTC date and time for wall-clock stamps, seconds for relative ones."""
    if abs(t_ns) >= EPOCH_LIKE_NS:
        when = datetime.fromtimestamp(t_ns // NS_PER_S, tz=UTC)
        return when.strftime("%Y-%m-%dT%H:%M:%S") + f".{(t_ns % NS_PER_S) // 1_000_000:03d}Z"
    return f"{t_ns / NS_PER_S:.3f} s"


def fmt_rate(rate_hz: float) -> str:
    """A rate to put in a config: 3 significant digits, no trailing zeros (20, 7.39, 100)."""
    return f"{rate_hz:.3g}"


def _remedy(clock: str, rate_hz: float | None, *, log_first: bool) -> str:
    rate = fmt_rate(rate_hz) if rate_hz else "<rate>"
    rebuild = f"`time: {{rate_hz: {rate}}}` (time from the row index, uniform from the first stamp)"
    if clock == "header" and log_first:
        return f"set `clock: log` for this stream, or {rebuild}"
    if clock == "header":
        return f"{rebuild} if the stream is uniformly sampled, or `clock: log`"
    return f"{rebuild} if the stream is uniformly sampled"


def check_stamps(stamps_ns: np.ndarray, *, clock: str, log_ns: np.ndarray | None = None,
                 label: str | None = None) -> StampCheck:
    """Check one stream's stamps (storage order, before the stream's offset); see the module docstring.

    ``log_ns``: the log time of the same messages (a ROS log), used by the ``far_from_log`` check and to
    estimate the rate when the stamps themselves cannot. ``label`` names the stamps in the messages (default
    from the clock).
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    n = int(t.size)
    checked = label or {"header": "header stamps", "log": "log times", "column": "time column"}.get(clock, clock)
    # One scratch array holds the intervals, then header - log; each median partitions it in place: fresh pages
    # of stamp-sized temporaries are much of a long stream's check (docs/benchmarks.md, "Stamp checks").
    work = np.empty(n, dtype=np.int64)
    diffs = np.subtract(t[1:], t[:-1], out=work[:max(n - 1, 0)])
    zeros = int((t == 0).sum())
    dup_mask = diffs == 0
    duplicates = int(dup_mask.sum())
    steps = np.flatnonzero(diffs < 0)
    positive = diffs if duplicates == 0 and steps.size == 0 else diffs[diffs > 0]
    step_ns = float(np.median(positive, overwrite_input=True)) if positive.size else None
    del diffs, positive  # partitioned: from here on ``work`` is scratch
    span_ns = int(t.max()) - int(t.min()) if n else 0
    mean_ns = span_ns / (n - 1) if n > 1 and span_ns > 0 else None
    offset_ns: int | None = None
    if clock == "header" and log_ns is not None and n and len(log_ns) == n:
        ahead = np.subtract(t, np.asarray(log_ns, dtype=np.int64), out=work)
        offset_ns = int(np.median(ahead, overwrite_input=True))
    rate_hz = NS_PER_S / mean_ns if mean_ns else None
    if rate_hz is None and log_ns is not None and len(log_ns) > 1:
        log_span = int(np.max(log_ns)) - int(np.min(log_ns))
        rate_hz = (len(log_ns) - 1) * NS_PER_S / log_span if log_span > 0 else None
    log_first = log_ns is not None

    warnings: list[StampWarning] = []
    if clock == "header" and zeros:
        what = "all" if zeros == n else f"{zeros} of"
        at = np.flatnonzero(t == 0)[:N_EXAMPLES].tolist()
        warnings.append(StampWarning(
            "zero", f"{what} {n} {checked} are 0 (a simulator or driver that never fills the header)",
            _remedy(clock, rate_hz, log_first=log_first), zeros,
            [f"message {i}" + (f" logged at {fmt_ns(int(log_ns[i]))}" if log_ns is not None else "") for i in at]))
    if n > 1 and duplicates == n - 1 and not (clock == "header" and zeros == n):
        warnings.append(StampWarning(
            "constant", f"all {n} {checked} are {fmt_ns(int(t[0]))}",
            _remedy(clock, rate_hz, log_first=log_first), n, [fmt_ns(int(t[0]))]))
    if offset_ns is not None and abs(offset_ns) > DAY_NS and zeros < n:
        sim = abs(int(np.median(t))) < EPOCH_LIKE_NS <= abs(int(np.median(np.asarray(log_ns))))
        kind = " (simulation time?)" if sim else ""
        lo, hi = int(t.min()), int(t.max())
        lmin, lmax = int(np.min(log_ns)), int(np.max(log_ns))  # type: ignore[arg-type]
        warnings.append(StampWarning(
            "far_from_log", f"{checked} span {fmt_ns(lo)} to {fmt_ns(hi)}{kind} while log time spans "
            f"{fmt_ns(lmin)} to {fmt_ns(lmax)}: median header - log = {offset_ns / DAY_NS:.1f} days; streams on "
            "log time will not overlap this one", _remedy(clock, rate_hz, log_first=True), n,
            [fmt_ns(lo), fmt_ns(hi)]))
    constant = n > 1 and duplicates == n - 1
    fraction = duplicates / (n - 1) if n > 1 else 0.0
    if duplicates and not constant and fraction >= DUPLICATE_WARN_FRACTION:
        runs = _longest_runs(t, dup_mask)
        warnings.append(StampWarning(
            "duplicates", f"{duplicates} of {n} {checked} repeat the one before ({100 * fraction:.0f}% of the "
            f"intervals); sync averages the samples that share a stamp",
            _remedy(clock, rate_hz, log_first=log_first), duplicates, runs))
    # In time order a value is new wherever it differs from the one before (np.unique is slow on 1M stamps); when
    # no stamp steps back the stamps are in that order already and the differing intervals are the non-zero diffs.
    if steps.size:
        distinct = 1 + int(np.count_nonzero(np.diff(np.sort(t))))
    else:
        distinct = n - duplicates if n else 0
    if step_ns is not None and mean_ns is not None and not constant and step_ns >= QUANTIZED_RATIO * mean_ns:
        warnings.append(StampWarning(
            "quantized", f"distinct {checked} are typically {step_ns / NS_PER_S:.3g} s apart while the samples "
            f"come every {mean_ns / NS_PER_S:.3g} s on average ({distinct} distinct values for {n} samples): "
            "the time was rounded (3 significant digits?)",
            _remedy(clock, rate_hz, log_first=log_first), n - distinct,
            [fmt_ns(int(v)) for v in t[:: max(1, n // N_EXAMPLES)][:N_EXAMPLES]]))
    if steps.size:
        warnings.append(StampWarning(
            "steps_back", f"{steps.size} of {n} {checked} are earlier than the one before; ingest sorts the "
            "samples by time", _remedy(clock, rate_hz, log_first=log_first).replace(
                " if the stream", " if the order of the rows is the true order and the stream"), int(steps.size),
            [f"message {i + 1}: {fmt_ns(int(t[i]))} -> {fmt_ns(int(t[i + 1]))}" for i in steps[:N_EXAMPLES]]))
    return StampCheck(
        checked=checked, count=n, zeros=zeros, distinct=distinct, duplicates=duplicates,
        duplicate_fraction=fraction, median_step_s=step_ns / NS_PER_S if step_ns is not None else None,
        mean_interval_s=mean_ns / NS_PER_S if mean_ns else None, steps_back=int(steps.size),
        header_minus_log_s=offset_ns / NS_PER_S if offset_ns is not None else None, warnings=warnings)


def _longest_runs(t: np.ndarray, dup_mask: np.ndarray) -> list[str]:
    """The longest runs of equal stamps, as "value x count" (earliest first among equals)."""
    starts = np.flatnonzero(np.concatenate([[True], ~dup_mask]))
    lengths = np.diff(np.concatenate([starts, [t.size]]))
    order = np.argsort(-lengths, kind="stable")[:N_EXAMPLES]
    return [f"{fmt_ns(int(t[starts[i]]))} x{int(lengths[i])}" for i in order if lengths[i] > 1]


def uniform_times(first_ns: int, rows: np.ndarray, rate_hz: float) -> np.ndarray:
    """``first + (k - k0) / rate`` in int64 ns for row indices ``rows`` (k0 = rows[0]); the ``time`` option."""
    k = np.asarray(rows, dtype=np.int64)
    if k.size == 0:
        return np.empty(0, dtype=np.int64)
    steps = np.rint((k - k[0]).astype(np.float64) * (NS_PER_S / rate_hz))
    last = float(first_ns) + float(steps.max(initial=0.0))
    if not last < 2.0**63:  # the cast below would wrap round to stamps centuries back, without a word
        raise ValueError(f"row {int(k.max() - k[0])} at {rate_hz:g} Hz from the first stamp is beyond int64 "
                         "nanoseconds (year 2262)")
    return np.int64(first_ns) + steps.astype(np.int64)


@dataclass(frozen=True)
class RebuildCheck:
    """A time rebuilt at ``rate_hz`` against the stream's own stamps, end to end (:func:`check_rebuild`).

    ``rows``: row intervals from the first to the last sample; ``stamps_s`` / ``rebuilt_s``: how far the stamps
    and the rebuilt times advance over them; ``allowed_s``: what the stamps' rounding allows at the two ends;
    ``stamps_rate_hz``: the rate the stamps imply; ``suggested``: that rate with the fewest digits (3 or more)
    whose rebuild stays within half of ``allowed_s``.
    """

    rate_hz: float
    rows: int
    stamps_s: float
    rebuilt_s: float
    allowed_s: float
    stamps_rate_hz: float
    suggested: str

    @property
    def drift_s(self) -> float:
        return self.rebuilt_s - self.stamps_s

    @property
    def ok(self) -> bool:
        return abs(self.drift_s) <= self.allowed_s

    def message(self, where: str) -> str:
        """What is wrong, naming ``where`` (the file) and the rate the stamps imply."""
        return (f"time: {{rate_hz: {self.rate_hz:g}}} but the stamps of {where} advance {self.stamps_s:.6g} s over "
                f"{self.rows} rows: {self.suggested} Hz; rebuilt at {self.rate_hz:g} Hz they would span "
                f"{self.rebuilt_s:.6g} s, {abs(self.drift_s):.3g} s off where the stamps' rounding allows "
                f"{self.allowed_s:.3g} s")

    def remedy(self) -> str:
        return (f"set rate_hz: {self.suggested} (the rows are uniformly sampled), or remove `time:` to keep the "
                "stamps (a gap in the rows makes any rate wrong)")


#: positive intervals at each end whose median is the stamps' resolution there (:func:`check_rebuild`)
END_STEPS = 5


def check_rebuild(stamps_ns: np.ndarray, rows: np.ndarray, rate_hz: float) -> RebuildCheck | None:
    """Do times rebuilt at ``rate_hz`` from the row slots ``rows`` span what the stamps span, first to last row?

    The stamps may be rounded (3 significant digits: 1 s steps past 100 s), so they may differ from a right
    rebuild by their resolution at each end: the median of the first and of the last :data:`END_STEPS` positive
    intervals (a step at least; a sample interval where the stamps resolve every sample). None where the stamps
    carry no time to check against (fewer than two steps forward: zero or constant stamps).
    """
    t = np.asarray(stamps_ns, dtype=np.int64)
    k = np.asarray(rows, dtype=np.int64)
    if t.size < 2 or k.size != t.size:
        return None
    diffs = np.diff(t)
    forward = np.flatnonzero(diffs > 0)
    span_ns = int(t[-1]) - int(t[0])
    n_rows = int(k[-1] - k[0])
    if forward.size < 2 or span_ns <= 0 or n_rows <= 0:
        return None
    allowed_ns = float(np.median(diffs[forward[:END_STEPS]])) + float(np.median(diffs[forward[-END_STEPS:]]))
    rebuilt_ns = float(np.rint(n_rows * (NS_PER_S / rate_hz)))
    implied = n_rows * NS_PER_S / span_ns
    suggested = f"{implied:.12g}"
    for digits in range(3, 13):
        text = f"{implied:.{digits}g}"
        if abs(n_rows * NS_PER_S / float(text) - span_ns) <= allowed_ns / 2:
            suggested = text
            break
    return RebuildCheck(rate_hz=rate_hz, rows=n_rows, stamps_s=span_ns / NS_PER_S, rebuilt_s=rebuilt_ns / NS_PER_S,
                        allowed_s=allowed_ns / NS_PER_S, stamps_rate_hz=implied, suggested=suggested)


def time_stats(t_ns: np.ndarray) -> dict[str, Any]:
    """Span, mean rate and largest gap of a stamp array (in the order given, so also counts steps back)."""
    n = int(t_ns.size)
    out: dict[str, Any] = {"count": n, "first_ns": None, "last_ns": None, "span_s": 0.0,
                           "mean_rate_hz": None, "largest_gap_s": None, "steps_back": 0}
    if n == 0:
        return out
    lo, hi = int(t_ns.min()), int(t_ns.max())
    out.update(first_ns=lo, last_ns=hi, span_s=(hi - lo) / 1e9)
    if n > 1:
        steps_back, largest = _steps(t_ns)
        out["steps_back"] = steps_back
        if steps_back:
            largest = np.diff(np.sort(t_ns)).max()
        out["largest_gap_s"] = float(largest) / 1e9
        out["mean_rate_hz"] = (n - 1) / ((hi - lo) / 1e9) if hi > lo else None
    return out


def _steps(t_ns: np.ndarray, block: int = 1 << 16) -> tuple[int, Any]:
    """How many of the intervals of ``t_ns`` (n > 1) are negative, and the largest interval (of t_ns's dtype).

    Block by block through one small array: every call of a long stream otherwise faulted in its intervals as a
    fresh array, twice per stream (its stamps and its log times).
    """
    n = int(t_ns.size)
    work = np.empty(min(block, n - 1), dtype=t_ns.dtype)
    back, largest = 0, None
    for lo in range(0, n - 1, block):
        hi = min(lo + block, n - 1)
        step = np.subtract(t_ns[lo + 1:hi + 1], t_ns[lo:hi], out=work[:hi - lo])
        back += int(np.count_nonzero(step < 0))
        largest = step.max() if largest is None else max(largest, step.max())
    assert largest is not None
    return back, largest
