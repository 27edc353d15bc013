"""Dynamics for rollouts: callables ``f(nu (B, k), inputs (B, m)) -> nudot (B, k)`` over a batch of B trajectories.

- :class:`DecoupledDynamics`: ``M nudot = tau - C(nu) nu - d(nu)`` with one damping function per DOF
  (``inputs`` = generalized forces of the simulated DOFs, already minus restoring forces if any). M is the
  sub-matrix of the simulated DOFs (the others held at zero velocity and acceleration).
- :class:`CoupledDynamics`: ``nudot = F(nu, n)`` for any fitted estimator with ``predict(X)``,
  ``X = [nu..., n...]`` (e.g. ``[u v r n1 n2 n3]`` -> ``[udot vdot rdot]``).

:func:`stack` steps several dynamics as one batch (member ``b`` follows ``dynamics[group[b]]``).
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from pipeline.rollout.tables import Table1D, TableStack, take
from pipeline.vocabulary import DOFS

log = logging.getLogger(__name__)

Dynamics = Callable[[np.ndarray, np.ndarray], np.ndarray]


class DecoupledDynamics:
    """``nudot = M_k^-1 (inputs - C(nu) nu - d(nu))`` over the DOFs ``dofs``.

    ``M`` is 6x6; ``coriolis(M, nu6 (B, 6)) -> (B, 6)`` (e.g. ``pipeline.physics.coriolis_force``) or None;
    ``damping[dof](x (B,)) -> (B,)`` (a :class:`Table1D`, or any callable).
    """

    def __init__(self, M: np.ndarray, dofs: Sequence[str], damping: Mapping[str, Callable[[np.ndarray], np.ndarray]],
                 coriolis: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> None:
        self.M = np.asarray(M, dtype=float)
        self.dofs = list(dofs)
        self.idx = [DOFS.index(d) for d in self.dofs]
        self.M_inv = np.linalg.inv(self.M[np.ix_(self.idx, self.idx)])
        self.damping = dict(damping)
        self.coriolis = coriolis
        self.Q = None if coriolis is None else self._quadratic_form(coriolis)

    def _quadratic_form(self, coriolis: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray | None:
        """``C(nu) nu`` restricted to the DOFs is a quadratic form ``Q[i, j, l] nu_j nu_l``: probe it once
        (polarization), check it at random points, and evaluate it with one einsum per call from then on."""
        k = len(self.idx)

        def c(x: np.ndarray) -> np.ndarray:
            nu6 = np.zeros((x.shape[0], 6))
            nu6[:, self.idx] = x
            return np.asarray(coriolis(self.M, nu6), dtype=float)[:, self.idx]

        eye = np.eye(k)
        diag = c(eye)
        pairs = (eye[:, None, :] + eye[None, :, :]).reshape(k * k, k)
        both = c(pairs).reshape(k, k, k)
        Q = 0.5 * (both - diag[:, None, :] - diag[None, :, :])
        Q[np.arange(k), np.arange(k)] = diag
        Q = np.transpose(Q, (2, 0, 1))  # Q[i, j, l]
        x = np.random.default_rng(0).standard_normal((4, k))
        direct = c(x)
        if not np.allclose(np.einsum("ijl,bj,bl->bi", Q, x, x), direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max()):
            log.info("C(nu) nu is not a quadratic form in the simulated DOFs; calling it at every step")
            return None
        return Q

    def take(self, members: np.ndarray) -> DecoupledDynamics:
        """The dynamics of batch members ``members`` (per-member damping tables taken, see :func:`take`)."""
        damping = {d: take(t, members) for d, t in self.damping.items()}
        if all(damping[d] is self.damping[d] for d in damping):
            return self
        other = copy.copy(self)
        other.damping = damping
        return other

    def __call__(self, nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
        rhs = tau - np.column_stack([self.damping[d](nu[:, j]) for j, d in enumerate(self.dofs)])
        if self.Q is not None:
            rhs = rhs - np.einsum("ijl,bj,bl->bi", self.Q, nu, nu, optimize=False)
        elif self.coriolis is not None:
            nu6 = np.zeros((nu.shape[0], 6))
            nu6[:, self.idx] = nu
            rhs = rhs - self.coriolis(self.M, nu6)[:, self.idx]
        return rhs @ self.M_inv.T


def fast_predictor(estimator: Any) -> Callable[[np.ndarray], np.ndarray] | None:
    """The estimator's own fast ``predict`` (its ``fast_predictor()`` method, e.g.
    :meth:`pipeline.models.svr.PerOutputRegressor.fast_predictor`), or None where it offers none."""
    method = getattr(estimator, "fast_predictor", None)
    return method() if callable(method) else None


class CoupledDynamics:
    """``nudot = estimator.predict([nu, inputs])`` for a fitted multi-output estimator (a protocol, any library).

    A rollout calls it four times per step with a small batch, where scikit-learn's per-call input validation
    costs more than the model itself; an estimator that offers a fast predictor (:func:`fast_predictor`) is
    called through it (equal to ``predict`` to float rounding). ``fast=False`` always calls ``predict``.
    """

    def __init__(self, estimator: Any, *, fast: bool = True) -> None:
        self.estimator = estimator
        self._predict = (fast_predictor(estimator) if fast else None) or estimator.predict

    def __call__(self, nu: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        out = np.asarray(self._predict(np.hstack([nu, inputs])), dtype=float)
        return out.reshape(nu.shape)


def stack(dynamics: Sequence[Dynamics], group: np.ndarray) -> Dynamics:
    """Member ``b`` of a batch follows ``dynamics[group[b]]`` (row ``b``'s rank in its group of that one's
    per-member tables). :class:`DecoupledDynamics` with the same M, DOFs and Coriolis term and
    :class:`Table1D` damping become one such dynamics over a :class:`TableStack` (one call per RK4 stage for all
    of them); anything else a :class:`MemberStack` (one call per dynamics)."""
    group = np.asarray(group, dtype=np.intp)
    first = dynamics[0] if dynamics else None
    if not isinstance(first, DecoupledDynamics) or not all(
            isinstance(g, DecoupledDynamics) and g.dofs == first.dofs and np.array_equal(g.M, first.M)
            and g.coriolis is first.coriolis and all(isinstance(g.damping[d], Table1D) for d in g.dofs)
            for g in dynamics):
        return MemberStack(dynamics, group)
    local = np.empty(group.size, dtype=np.intp)
    for j in range(len(dynamics)):
        rows = np.flatnonzero(group == j)
        local[rows] = np.arange(rows.size)
    out = copy.copy(first)
    out.damping = {d: TableStack.of([g.damping[d] for g in dynamics], group, local) for d in first.dofs}
    return out


class MemberStack:
    """Several dynamics stepped as one batch: member ``b`` follows ``dynamics[group[b]]`` (one call per distinct
    dynamics and RK4 stage, on its rows only)."""

    def __init__(self, dynamics: Sequence[Dynamics], group: np.ndarray) -> None:
        self.dynamics = list(dynamics)
        self.group = np.asarray(group, dtype=np.intp)
        self._rows = [np.flatnonzero(self.group == g) for g in range(len(self.dynamics))]

    def __call__(self, nu: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        out = np.empty_like(nu, dtype=float)
        for g, rows in zip(self.dynamics, self._rows, strict=True):
            if rows.size:
                out[rows] = g(nu[rows], inputs[rows])
        return out

    def take(self, members: np.ndarray) -> MemberStack:
        local = np.empty(self.group.size, dtype=np.intp)  # each member's row within its own group
        for rows in self._rows:
            local[rows] = np.arange(rows.size)
        group = self.group[members]
        return MemberStack([take(g, local[members[group == j]]) for j, g in enumerate(self.dynamics)], group)
