"""Learned 1-D damping models as dense lookup tables, so that a rollout step costs numpy operations instead of one
scikit-learn ``predict`` per step (the table error is far below the noise; tested).

:class:`Table1D` is one function of one variable on a uniform grid (or one per batch member); :class:`TableStack`
holds batch members' tables on different grids in one array; :func:`take` restricts anything with per-member
parameters to some members of a batch.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np


class Table1D:
    """A function of one variable on a uniform grid; ``values`` is ``(G,)`` or one table per batch member ``(B, G)``.

    Linear interpolation inside ``[lo, hi]``, linear extrapolation with the end slopes outside.
    """

    def __init__(self, lo: float, hi: float, values: np.ndarray) -> None:
        self.lo, self.hi = float(lo), float(hi)
        self.values = np.asarray(values, dtype=float)
        self.n = self.values.shape[-1]
        self.h = (self.hi - self.lo) / (self.n - 1)

    @classmethod
    def from_model(cls, model: Any, lo: float, hi: float, n_points: int = 2001) -> Table1D:
        grid = np.linspace(lo, hi, n_points)
        return cls(lo, hi, np.asarray(model.predict(grid[:, None]), dtype=float).ravel())

    def grid(self) -> np.ndarray:
        return np.linspace(self.lo, self.hi, self.n)

    def take(self, members: np.ndarray) -> Table1D:
        """The tables of batch members ``members`` (repeats allowed); a shared ``(G,)`` table is returned as is."""
        return self if self.values.ndim == 1 else Table1D(self.lo, self.hi, self.values[members])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        s = (np.asarray(x, dtype=float) - self.lo) / self.h
        i = np.fmin(np.fmax(s, 0.0), self.n - 2).astype(np.intp)  # fmax/fmin drop NaN; truncation = floor here
        w = s - i
        if self.values.ndim == 1:
            a, b = self.values[i], self.values[i + 1]
        else:
            rows = np.arange(self.values.shape[0])
            a, b = self.values[rows, i], self.values[rows, i + 1]
        return a + w * (b - a)


def table_range(x: np.ndarray, margin: float = 1.0) -> tuple[float, float]:
    """The table span for measured values ``x``: their range widened by ``margin`` ranges on each side."""
    lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
    width = max(hi - lo, 1e-6)
    return lo - margin * width, hi + margin * width


def damping_tables(models: Mapping[str, Any], ranges: Mapping[str, tuple[float, float]], n_points: int = 2001
                   ) -> dict[str, Table1D]:
    """A :class:`Table1D` of each DOF's fitted damping model over ``ranges[dof]`` (see :func:`table_range`)."""
    return {d: Table1D.from_model(m, *ranges[d], n_points=n_points) for d, m in models.items()}


def band_tables(models: Mapping[str, Any], ranges: Mapping[str, tuple[float, float]], n_samples: int, seed: int = 0,
                n_points: int = 401) -> dict[str, Table1D]:
    """Per DOF, ``n_samples`` posterior functions of a GP-like model (``sample_functions``) as batch tables."""
    out = {}
    for j, (d, m) in enumerate(models.items()):
        grid = np.linspace(*ranges[d], n_points)
        out[d] = Table1D(*ranges[d], m.sample_functions(grid[:, None], n_samples, random_state=seed + j))
    return out


def take(f: Any, members: np.ndarray) -> Any:
    """``f`` restricted to (or repeated over) the batch members ``members``: ``f.take(members)`` where ``f`` has
    per-member parameters (a :class:`Table1D` of ``(B, G)`` values, dynamics built on such tables), else ``f``
    itself (a function of each row alone)."""
    method = getattr(f, "take", None)
    return f if method is None else method(np.asarray(members, dtype=np.intp))


class TableStack:
    """Batch members' 1-D tables on different grids in one call: member ``b`` reads the table at ``offset[b]`` of
    ``flat`` (``n[b]`` points from ``lo[b]`` in steps ``h[b]``), with :class:`Table1D`'s arithmetic."""

    def __init__(self, flat: np.ndarray, offset: np.ndarray, lo: np.ndarray, h: np.ndarray, n: np.ndarray) -> None:
        self.flat, self.offset, self.lo, self.h, self.n = flat, offset, lo, h, n

    @classmethod
    def of(cls, tables: Sequence[Table1D], group: np.ndarray, local: np.ndarray) -> TableStack:
        """Member ``b`` gets ``tables[group[b]]`` (its row ``local[b]`` where that table is per member)."""
        blocks = [t.values.ravel() for t in tables]
        base = np.concatenate([[0], np.cumsum([x.size for x in blocks])[:-1]]).astype(np.intp)
        per_member = np.array([t.values.ndim == 2 for t in tables])
        size = np.array([t.n for t in tables], dtype=np.intp)
        offset = base[group] + np.where(per_member[group], local * size[group], 0)
        return cls(np.concatenate(blocks), offset, np.array([t.lo for t in tables])[group],
                   np.array([t.h for t in tables])[group], (size[group] - 2).astype(float))

    def take(self, members: np.ndarray) -> TableStack:
        return TableStack(self.flat, self.offset[members], self.lo[members], self.h[members], self.n[members])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        s = (np.asarray(x, dtype=float) - self.lo) / self.h
        i = np.fmin(np.fmax(s, 0.0), self.n).astype(np.intp)
        w = s - i
        a, b = self.flat[self.offset + i], self.flat[self.offset + i + 1]
        return a + w * (b - a)
