"""The rigid body: its config model and the 6x6 rigid-body mass matrix M_RB built from it.

In the config layer because the vehicle's validation checks M = M_RB + M_A (:class:`~pipeline.config.vehicle.Vehicle`);
:mod:`pipeline.physics` builds the equation of motion on these.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field, ValidationInfo, field_validator, model_validator

from pipeline.config import checks
from pipeline.config.base import Frozen, Vec3
from pipeline.errors import ConfigError


class RigidBody(Frozen):
    mass_kg: float = Field(gt=0)
    inertia_kgm2: list[list[float]] = Field(description="3x3 inertia about the CG, body axes: symmetric, positive "
                                            "definite.")
    cg_m: Vec3 = (0.0, 0.0, 0.0)
    cb_m: Vec3 = (0.0, 0.0, 0.0)
    buoyancy_N: float | None = Field(None, ge=0, description="Buoyancy; None: equal to the weight (neutral). At "
                                     f"most {checks.MAX_BUOYANCY_RATIO:g} times the weight.")
    gravity_mps2: float = Field(9.81, ge=0.1, le=100.0, description="Gravity (m/s^2, 0.1 to 100: the Moon's 1.6 "
                                "to Jupiter's 25, with room).")

    @field_validator("inertia_kgm2")
    @classmethod
    def _inertia_spd(cls, rows: list[list[float]]) -> list[list[float]]:
        inertia = checks.square(rows, 3, "the inertia")
        checks.check_symmetric(inertia, "the inertia")
        checks.check_positive_definite(inertia, "the inertia")
        return rows

    @field_validator("cg_m", "cb_m")
    @classmethod
    def _centre_on_board(cls, point: tuple[float, float, float], info: ValidationInfo) -> tuple[float, float, float]:
        return checks.check_body_point(point, str(info.field_name))  # type: ignore[return-value]

    @model_validator(mode="after")
    def _weight_finite(self) -> RigidBody:
        if not math.isfinite(self.mass_kg * self.gravity_mps2):
            raise checks.KeyedError("mass_kg", f"the weight mass_kg * gravity_mps2 = {self.mass_kg:g} * "
                                    f"{self.gravity_mps2:g} is not a finite number of newtons")
        return self

    @model_validator(mode="after")
    def _mass_physical(self) -> RigidBody:
        """After the weight check, which names the overflow of a mass like 1e308 itself."""
        if not checks.MIN_MASS_KG <= self.mass_kg <= checks.MAX_MASS_KG:
            raise checks.KeyedError("mass_kg", f"mass_kg {self.mass_kg:g} is outside {checks.MIN_MASS_KG:g} to "
                                    f"{checks.MAX_MASS_KG:g} kg (a few grams to the largest submarines)")
        return self

    @model_validator(mode="after")
    def _buoyancy_physical(self) -> RigidBody:
        weight = self.mass_kg * self.gravity_mps2
        if self.buoyancy_N is not None and self.buoyancy_N > checks.MAX_BUOYANCY_RATIO * weight:
            raise checks.KeyedError("buoyancy_N", f"buoyancy_N {self.buoyancy_N:g} N is more than "
                                    f"{checks.MAX_BUOYANCY_RATIO:g} times the weight {weight:g} N (mass_kg * "
                                    "gravity_mps2): accepted 0 to that (a unit or typing error?)")
        return self


def skew(a: np.ndarray) -> np.ndarray:
    """Skew-symmetric cross-product matrix S(a), with S(a) b = a x b; ``a`` (..., 3) -> (..., 3, 3)."""
    a = np.asarray(a, dtype=float)
    out = np.zeros(a.shape[:-1] + (3, 3))
    out[..., 0, 1] = -a[..., 2]
    out[..., 0, 2] = a[..., 1]
    out[..., 1, 0] = a[..., 2]
    out[..., 1, 2] = -a[..., 0]
    out[..., 2, 0] = -a[..., 1]
    out[..., 2, 1] = a[..., 0]
    return out


def check_spd(matrix: np.ndarray, field: str, what: str) -> None:
    """A ConfigError naming ``field`` unless ``matrix`` is finite, symmetric and positive definite."""
    if not np.all(np.isfinite(matrix)):
        raise ConfigError(f"{what} has non-finite entries", field=field)
    if not np.allclose(matrix, matrix.T, rtol=1e-9, atol=1e-9 * max(1.0, float(np.abs(matrix).max()))):
        raise ConfigError(f"{what} must be symmetric; max |A - A^T| = {np.abs(matrix - matrix.T).max():.3g}",
                          field=field)
    eig = np.linalg.eigvalsh(0.5 * (matrix + matrix.T))
    if eig.min() <= 0:
        raise ConfigError(f"{what} must be positive definite; smallest eigenvalue {eig.min():.6g}", field=field)


def rigid_body_mass(rb: RigidBody) -> np.ndarray:
    """6x6 rigid-body mass matrix about the body origin (Fossen 2011, eq. 3.44).

    ``M_RB = [[m I, -m S(r_g)], [m S(r_g), I_o]]`` with ``I_o = I_g - m S(r_g)^2`` (parallel axes), where
    ``rb.inertia_kgm2`` is the inertia about the CG and ``r_g = rb.cg_m``.
    """
    inertia = np.asarray(rb.inertia_kgm2, dtype=float)
    if inertia.shape != (3, 3):
        raise ConfigError(f"inertia must be 3x3, found shape {inertia.shape}", field="rigid_body.inertia_kgm2")
    check_spd(inertia, "rigid_body.inertia_kgm2", "rigid-body inertia")
    m = rb.mass_kg
    s = skew(np.asarray(rb.cg_m, dtype=float))
    out = np.zeros((6, 6))
    out[:3, :3] = m * np.eye(3)
    out[:3, 3:] = -m * s
    out[3:, :3] = m * s
    out[3:, 3:] = inertia - m * s @ s
    return out
