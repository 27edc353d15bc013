"""Checks the config models share: names that may reach a path, matrices, clock offsets, keyed errors.

A validator that knows *which key* is wrong (a matrix entry, a signal's unit) raises :class:`KeyedError`;
:func:`pipeline.config.parse` appends its ``key`` to the location pydantic gives, so the ConfigError names
``rigid_body.inertia_kgm2`` even when the check runs on the whole vehicle.
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Sequence

import numpy as np

#: A name that becomes (part of) a file or directory name: a stream, a trial, a model. Letters, digits,
#: ``_ . -``; not starting with a dot (so neither ``.``, ``..`` nor a hidden file).
SAFE_NAME = re.compile(r"^[A-Za-z0-9_\-][A-Za-z0-9_.\-]*$")
SAFE_NAME_RULE = "letters, digits, '_', '.' and '-', not starting with '.'"

#: Largest |clock offset| (s): 2^62 ns, about 146 years. A real offset (a driver's latency, a clock running
#: ahead, or boot-relative stamps moved onto the Unix epoch, ~1.7e9 s) is far below; beyond it, stamp plus
#: offset in int64 nanoseconds could overflow.
MAX_OFFSET_S = 2.0**62 / 1e9

#: Largest condition number of the mass matrix M = M_RB + M_A: solving M nu_dot = ... (the simulator) then
#: keeps at least 4 of float64's 16 significant digits. Real vehicles are at 10 to 10^4.
MAX_MASS_CONDITION = 1e12

#: Largest distance (m) of a body-axes point (a thruster, a sensor, the CG) from the reference point: the largest
#: submarines are under 200 m long; a point beyond is a unit or typing error (mm given as m, 1e9).
MAX_BODY_POINT_M = 1000.0

#: The masses a vehicle may have (kg): from a few grams (a micro robot) to 1e8 kg (the largest submarines are
#: under 5e7 kg); outside, a unit or typing error (1e-300, tonnes given as kg squared ...).
MIN_MASS_KG, MAX_MASS_KG = 1e-3, 1e8

#: The most buoyancy a vehicle may have, in weights: a float or a buoyant sensor body is a few weights; beyond ten
#: the restoring force dwarfs every other, and the number is a unit error (N given as kg of displacement x 1000).
MAX_BUOYANCY_RATIO = 10.0

#: A mounting angle (deg): within one turn either way; 1e261 deg is no angle (its sine is round-off).
MAX_ANGLE_DEG = 360.0


class KeyedError(ValueError):
    """A validation error that knows the offending key, relative to where the validator runs."""

    def __init__(self, key: str, message: str) -> None:
        self.key = key
        super().__init__(message)


def applies_to(pattern: str, trial: str) -> bool:
    """Whether a ``trials`` key (a trial name or a glob) names ``trial``."""
    return pattern == trial or fnmatch.fnmatchcase(trial, pattern)


def check_safe_name(name: str, what: str) -> str:
    """``name`` if it is safe as a file name (:data:`SAFE_NAME`); a ValueError saying why not otherwise."""
    if not isinstance(name, str) or not SAFE_NAME.match(name):
        raise ValueError(f"{what} {name!r} is not a safe name: use {SAFE_NAME_RULE} (it becomes part of a path)")
    return name


def check_offset_s(value: float | None, what: str = "offset_s") -> float | None:
    if value is not None and abs(value) > MAX_OFFSET_S:
        raise ValueError(f"{what} {value:g} s is beyond +/-{MAX_OFFSET_S:.3g} s (2^62 ns, ~146 years): "
                         "a clock offset that large cannot be meant")
    return value


def check_body_point(point: Sequence[float], what: str) -> Sequence[float]:
    """``point`` (body axes, m) if within :data:`MAX_BODY_POINT_M` of the reference point; a ValueError otherwise."""
    far = max(abs(float(x)) for x in point)
    if far > MAX_BODY_POINT_M:
        raise ValueError(f"{what} {list(point)} lies {far:g} m from the reference point; accepted: within "
                         f"{MAX_BODY_POINT_M:g} m on each axis (a vehicle is at most a few hundred metres long)")
    return point


def square(rows: Sequence[Sequence[float]], n: int, what: str) -> np.ndarray:
    """``rows`` as an n x n float array; a ValueError naming the shape found otherwise."""
    lengths = [len(r) for r in rows]
    if len(rows) != n or any(k != n for k in lengths):
        raise ValueError(f"{what} must be {n}x{n}; found {len(rows)} row(s) of length(s) {lengths}")
    return np.asarray(rows, dtype=float)


def _tolerance(matrix: np.ndarray) -> float:
    return 1e-9 * max(1.0, float(np.abs(matrix).max()))


def check_symmetric(matrix: np.ndarray, what: str) -> None:
    """Symmetric to the tolerance :mod:`pipeline.physics` uses (1e-9 relative)."""
    with np.errstate(over="ignore", invalid="ignore"):  # entries near 1.8e308 of opposite signs: an infinite gap
        gaps = np.abs(matrix - matrix.T)
    if float(gaps.max()) > _tolerance(matrix):
        i, j = np.unravel_index(int(np.argmax(gaps)), matrix.shape)
        raise ValueError(f"{what} must be symmetric; [{i}][{j}] = {matrix[i, j]:g} but [{j}][{i}] = "
                         f"{matrix[j, i]:g}")


def _symmetric_part(matrix: np.ndarray) -> np.ndarray:
    """(M + Mᵀ) / 2 without overflow: entries near the float maximum (1.8e308) stay finite."""
    return 0.5 * matrix + 0.5 * matrix.T


def smallest_eigenvalue(matrix: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(_symmetric_part(matrix)).min())


def check_positive_definite(matrix: np.ndarray, what: str) -> None:
    low = smallest_eigenvalue(matrix)
    if low <= 0:
        raise ValueError(f"{what} must be positive definite; smallest eigenvalue {low:.6g} "
                         f"(diagonal {np.diag(matrix).tolist()})")


def check_positive_semidefinite(matrix: np.ndarray, what: str, hint: str = "") -> None:
    low = smallest_eigenvalue(matrix)
    if low < -_tolerance(matrix):
        raise ValueError(f"{what} must be positive semi-definite; smallest eigenvalue {low:.6g} "
                         f"(diagonal {np.diag(matrix).tolist()}){hint}")


def check_conditioned(matrix: np.ndarray, what: str) -> None:
    """Checked before definiteness: the smallest eigenvalue of an ill-conditioned matrix is round-off."""
    eig = np.linalg.eigvalsh(_symmetric_part(matrix))
    size = np.abs(eig)
    if not np.all(np.isfinite(eig)) or size.max() > MAX_MASS_CONDITION * size.min():
        raise ValueError(f"{what} has eigenvalues from {eig.min():.3g} to {eig.max():.3g}: a condition number "
                         f"above {MAX_MASS_CONDITION:.0e} (a mass or inertia off by many orders of magnitude)")
