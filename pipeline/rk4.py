"""The classical fourth-order Runge-Kutta step, written once for every integrator of the project.

``f(x, u)`` is a right-hand side with the input ``u`` held over the step (zero-order hold). The state is a numpy
array (a batch) or, with ``axpy=list_axpy``, a Python list (the truth simulator's single state, where list
arithmetic costs far less than small arrays). Both do the same IEEE operations in the same order.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

Axpy = Callable[[Any, float, Any], Any]


def array_axpy(x: Any, a: float, k: Any) -> Any:
    """``x + a * k`` on numpy arrays."""
    return x + a * k


def list_axpy(x: list[float], a: float, k: list[float]) -> list[float]:
    """``x + a * k`` element by element on Python lists."""
    return [xi + a * ki for xi, ki in zip(x, k, strict=True)]


def rk4_slopes(f: Callable[[Any, Any], Any], x: Any, u: Any, h: float, axpy: Axpy = array_axpy) -> Any:
    """The four stages of an RK4 step of size ``h`` and their weighted sum ``k1 + 2 k2 + 2 k3 + k4``
    (the step is ``x + h / 6 * sum``, :func:`rk4_step`)."""
    k1 = f(x, u)
    k2 = f(axpy(x, 0.5 * h, k1), u)
    k3 = f(axpy(x, 0.5 * h, k2), u)
    k4 = f(axpy(x, h, k3), u)
    return axpy(axpy(axpy(k1, 2.0, k2), 2.0, k3), 1.0, k4)


def rk4_step(f: Callable[[Any, Any], Any], x: Any, u: Any, h: float, axpy: Axpy = array_axpy) -> Any:
    """One RK4 step of size ``h`` from ``x`` with ``u`` held: ``x + h / 6 * (k1 + 2 k2 + 2 k3 + k4)``."""
    return axpy(x, h / 6.0, rk4_slopes(f, x, u, h, axpy))
