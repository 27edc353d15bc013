"""Block bootstrap for fits on time-ordered rows: confidence intervals of coefficients whose errors are correlated
in time.

The rows of a trial are not independent: the targets are smoothed derivatives, and a model's error follows the
excitation, so a residual resembles its neighbours for seconds. Resampling single rows would count every 20-Hz
sample as a new observation, and the intervals would come out far too narrow. The non-overlapping block bootstrap
(Carlstein 1986, Ann. Statist. 14, 1171-1179; Lahiri 2003, *Resampling Methods for Dependent Data*, sec. 2.5)
cuts each contiguous run into blocks of ``L`` rows. A replicate draws, per run, as many of that run's blocks as it
has, with replacement, so each trial keeps its share of the rows. Its fit is the fit with every row weighted by its
block's count. The interval is the percentile interval of the replicates (Efron & Tibshirani 1993, *An
Introduction to the Bootstrap*, sec. 13.3), or, where a replicate costs a whole fit and there are few of them, the
estimate +- z times their SD (the same book, sec. 12.2).

Block length: ``L`` is 4 times the residuals' integrated autocorrelation time, the longest over the equations;
at least the length that gives :data:`MAX_BLOCKS` blocks, at most the one that leaves :data:`MIN_BLOCKS`. The time
is estimated by Geyer's initial positive sequence (Stat. Sci. 7 (1992) 473-483, sec. 3.3): autocorrelations
summed in pairs up to the first negative pair. Why 4: for an AR(1) error the blocks' sums then hold about seven
eighths of its long-run variance; the rest is the correlation across block edges, which the bootstrap loses. A
cap that binds (a short trial with slow errors) makes the intervals too narrow; the result says so
(``blocks_too_short``, beside ``block_rows`` and ``blocks``).
"""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

__all__ = ["MAX_BLOCKS", "MIN_BLOCKS", "integrated_time", "wanted_rows", "block_rows", "cut_blocks", "draw_counts",
           "percentile_interval", "refits", "resample_plan", "summary"]

#: fewer blocks than this and a replicate's spread says little: the block length is capped to leave this many
MIN_BLOCKS = 20
#: more blocks than this add cost (a replicate stacks every block's statistics), not accuracy: longer blocks then
MAX_BLOCKS = 200
#: block length in integrated autocorrelation times
BLOCK_FACTOR = 4.0


def integrated_time(e: np.ndarray) -> float:
    """tau = 1 + 2 sum_k rho_k of a series (rows), by Geyer's initial positive sequence; 1 for white noise."""
    e = np.asarray(e, dtype=float) - float(np.mean(e))
    n = e.size
    if n < 4 or not np.any(e):
        return 1.0
    f = np.fft.rfft(e, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    rho = acf / acf[0]
    pairs = rho[: (n - 1) // 2 * 2].reshape(-1, 2).sum(axis=1)  # Gamma_m = rho_2m + rho_2m+1
    stop = np.flatnonzero(pairs <= 0)
    m = int(stop[0]) if stop.size else pairs.size
    return max(2.0 * float(pairs[:m].sum()) - 1.0, 1.0)


def wanted_rows(residuals: np.ndarray, runs: list[tuple[int, int]]) -> int:
    """:data:`BLOCK_FACTOR` times the longest integrated time of the residuals' columns (each computed on the
    longest run), in rows: the block length the errors' correlation asks for."""
    residuals = np.asarray(residuals, dtype=float).reshape(len(residuals), -1)
    start, stop = max(runs, key=lambda r: r[1] - r[0])
    tau = max(integrated_time(residuals[start:stop, j]) for j in range(residuals.shape[1]))
    return int(np.ceil(BLOCK_FACTOR * tau))


def block_rows(residuals: np.ndarray, runs: list[tuple[int, int]]) -> int:
    """``L``: :func:`wanted_rows` within [the length that gives :data:`MAX_BLOCKS` blocks, the one that leaves
    :data:`MIN_BLOCKS`] (and at least 1 row)."""
    rows = sum(b - a for a, b in runs)
    return int(max(1, min(max(wanted_rows(residuals, runs), np.ceil(rows / MAX_BLOCKS)), rows // MIN_BLOCKS)))


def cut_blocks(runs: list[tuple[int, int]], length: int) -> list[tuple[int, int, int]]:
    """Consecutive blocks of ``length`` rows within each run, as (start, stop, run index); a run's last block
    takes its remainder when that is at least half a block, else joins the block before."""
    out = []
    for i, (a, b) in enumerate(runs):
        edges = list(range(a, b, length)) + [b]
        if len(edges) > 2 and edges[-1] - edges[-2] < length / 2:
            del edges[-2]
        out += [(s, e, i) for s, e in zip(edges[:-1], edges[1:], strict=True)]
    return out


def draw_counts(blocks: list[tuple[int, int, int]], n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """(n_boot, len(blocks)) counts: per replicate and run, that run's number of blocks drawn from its blocks with
    replacement."""
    runs = np.array([r for _, _, r in blocks])
    counts = np.zeros((n_boot, len(blocks)), dtype=np.int64)
    for run in np.unique(runs):
        members = np.flatnonzero(runs == run)
        counts[:, members] = rng.multinomial(members.size, np.full(members.size, 1.0 / members.size), size=n_boot)
    return counts


def percentile_interval(samples: np.ndarray, level: float) -> np.ndarray:
    """(2, p): the ((1 - level) / 2, (1 + level) / 2) quantiles of each column of ``samples`` (replicates, p)."""
    alpha = (1.0 - level) / 2.0
    return np.quantile(np.asarray(samples, dtype=float), [alpha, 1.0 - alpha], axis=0)


def resample_plan(residuals: np.ndarray, runs: list[tuple[int, int]], n_boot: int, seed: int
                  ) -> tuple[int, list[tuple[int, int, int]], np.ndarray, bool]:
    """For a fit on time-ordered rows with these residuals (rows first) in these runs (``(start, stop)``, e.g.
    one per trial; blocks are drawn within each, so every trial keeps its share): the block length, the blocks,
    each of ``n_boot`` replicates' block counts (seeded), and whether the blocks are shorter than the errors'
    correlation asks for (the cap of :data:`MIN_BLOCKS` bound: the intervals are too narrow)."""
    length = block_rows(residuals, runs)
    blocks = cut_blocks(runs, length)
    short = wanted_rows(residuals, runs) > length
    return length, blocks, draw_counts(blocks, n_boot, np.random.default_rng(seed)), short


def refits(replicate, X: np.ndarray, y: np.ndarray, blocks: list[tuple[int, int, int]], counts: np.ndarray,
           failures: tuple[type[BaseException], ...]) -> tuple[list[np.ndarray], int]:
    """``replicate`` (an unfitted estimator) fitted on each row of ``counts``' resampled blocks: the replicates'
    ``coef_`` in order, and how many raised one of ``failures`` (left out, counted)."""
    samples, failed = [], 0
    for c in counts:
        rows = np.concatenate([np.arange(a, b) for (a, b, _), k in zip(blocks, c, strict=True) for _ in range(k)])
        try:
            samples.append(replicate.fit(X[rows], y[rows]).coef_.copy())
        except failures:
            failed += 1
    return samples, failed


def summary(names: list[str], samples: list[np.ndarray], level: float, *, point: np.ndarray | None = None,
            length: int, blocks: int, failed: int, short: bool) -> dict:
    """A model card's record of the intervals: percentile intervals of the replicates, or with ``point`` (few
    replicates) the point estimate +- z times their SD; none unless at least half the replicates succeeded."""
    out = {"level": level, "method": "non-overlapping block bootstrap, "
           + ("percentile" if point is None else "normal (replicates' SD)"), "block_rows": length,
           "blocks": blocks, "blocks_too_short": short, "replicates": len(samples), "failed_replicates": failed,
           "intervals": {}}
    if len(samples) < failed or len(samples) < 2:
        return out
    if point is None:
        lo, hi = percentile_interval(np.asarray(samples), level)
    else:
        z = NormalDist().inv_cdf(0.5 + level / 2.0)
        half = z * np.std(np.asarray(samples), axis=0, ddof=1)
        lo, hi = np.asarray(point) - half, np.asarray(point) + half
    out["intervals"] = {k: [float(a), float(b)] for k, a, b in zip(names, lo, hi, strict=True)}
    return out
