"""The classical fourth-order Runge-Kutta step, written once for every integrator of the project.

``f(x, u)`` is a right-hand side with the input ``u`` held over the step (zero-order hold). The state is a numpy
array (a batch; :data:`ARRAYS`, the default) or a Python list (:data:`LISTS`: the truth simulator's single state,
where list arithmetic costs far less than small arrays). Both do the same IEEE operations in the same order.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple


class VectorOps(NamedTuple):
    """The two element-wise operations an RK4 step needs, for one kind of state."""

    axpy: Callable[[Any, float, Any], Any]  # x + a * k
    weighted_sum: Callable[[Any, Any, Any, Any], Any]  # k1 + 2 k2 + 2 k3 + k4


def _array_axpy(x: Any, a: float, k: Any) -> Any:
    return x + a * k


def _array_weighted_sum(k1: Any, k2: Any, k3: Any, k4: Any) -> Any:
    return k1 + 2 * k2 + 2 * k3 + k4


def _list_axpy(x: list[float], a: float, k: list[float]) -> list[float]:
    return [xi + a * ki for xi, ki in zip(x, k, strict=True)]


def _list_weighted_sum(k1: list[float], k2: list[float], k3: list[float], k4: list[float]) -> list[float]:
    return [a + 2.0 * b + 2.0 * c + d for a, b, c, d in zip(k1, k2, k3, k4, strict=True)]


ARRAYS = VectorOps(_array_axpy, _array_weighted_sum)
LISTS = VectorOps(_list_axpy, _list_weighted_sum)


def rk4_slopes(f: Callable[[Any, Any], Any], x: Any, u: Any, h: float, ops: VectorOps = ARRAYS) -> Any:
    """The four stages of an RK4 step of size ``h`` and their weighted sum ``k1 + 2 k2 + 2 k3 + k4``
    (the step is ``x + h / 6 * sum``, :func:`rk4_step`)."""
    k1 = f(x, u)
    k2 = f(ops.axpy(x, 0.5 * h, k1), u)
    k3 = f(ops.axpy(x, 0.5 * h, k2), u)
    k4 = f(ops.axpy(x, h, k3), u)
    return ops.weighted_sum(k1, k2, k3, k4)


def rk4_step(f: Callable[[Any, Any], Any], x: Any, u: Any, h: float, ops: VectorOps = ARRAYS) -> Any:
    """One RK4 step of size ``h`` from ``x`` with ``u`` held: ``x + h / 6 * (k1 + 2 k2 + 2 k3 + k4)``."""
    return ops.axpy(x, h / 6.0, rk4_slopes(f, x, u, h, ops))
