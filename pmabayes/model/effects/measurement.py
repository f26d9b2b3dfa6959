"""Measurement effects: what the sensor reports of the position."""

from __future__ import annotations

import math

import numba

from pmabayes.model.effects.base import Effect
from pmabayes.model.parameters import Normal, Parameter

__all__ = ["PositionOffset", "QuadraticSensor"]


@numba.njit(cache=True, error_model="numpy")
def _position_offset(q, time_s, position_m):
    n, batch = position_m.shape
    for k in range(n):
        for i in range(batch):
            position_m[k, i] += q[i, 0]


@numba.njit(cache=True, error_model="numpy")
def _position_offset_inverse(q, time_s, reading_m):
    return reading_m - q[0], 1.0


class PositionOffset(Effect):
    """Zero offset of the position sensor."""

    name = "position_offset"
    stage = "measurement"
    parameters = (
        Parameter(
            "x_offset", "m", 5e-4, Normal(0.0, 2e-3), null=0.0, per_experiment=True,
            description="constant offset of the encoder's zero from the unloaded length",
            latex=r"x_\mathrm{off}",
        ),
    )
    description = (
        "The encoder was zeroed away from the unloaded length, so every measured "
        "position is shifted by x_offset. In the residual: a constant bias, the same at "
        "every frequency, pressure and position."
    )
    physics = staticmethod(_position_offset)
    inverse = staticmethod(_position_offset_inverse)


@numba.njit(cache=True, error_model="numpy")
def _quadratic_sensor(q, time_s, position_m):
    n, batch = position_m.shape
    for k in range(n):
        for i in range(batch):
            x = position_m[k, i]
            position_m[k, i] = x + q[i, 0] * x * x


@numba.njit(cache=True, error_model="numpy")
def _quadratic_sensor_inverse(q, time_s, reading_m):
    # the root of c x^2 + x - r = 0 through x = r at c = 0, written 2 r / (1 + sqrt(1 +
    # 4 c r)) so that it is exact at c = 0 and loses no digits at small c; beyond the
    # map's fold (1 + 4 c r <= 0) no position gives the reading: the fold's position,
    # and a slope of 0 (such a reading says nothing of the velocity; an infinite slope
    # would make the closed loop's velocity estimate infinite)
    disc = 1.0 + 4.0 * q[0] * reading_m
    if disc <= 0.0:
        return -0.5 / q[0], 0.0
    root = math.sqrt(disc)
    return 2.0 * reading_m / (1.0 + root), 1.0 / root


class QuadraticSensor(Effect):
    """A position sensor whose reading curves with the position: ``x + c_qs x^2``."""

    name = "quadratic_sensor"
    stage = "measurement"
    parameters = (
        Parameter(
            "c_qs", "1/m", 0.5, Normal(0.0, 2.0), bounds=(-50.0, 50.0), null=0.0,
            description="curvature of the sensor's reading: measured position x + c_qs x^2, "
            "x from the unloaded length (a relative error c_qs x)",
            latex=r"c_\mathrm{qs}",
        ),
    )
    description = (
        "The position sensor (a string potentiometer's winding, a laser triangulation's "
        "angle, an encoder's scale against a thermal drift) is not linear: it reads x + "
        "c_qs x^2, with x the position from the unloaded length, a relative error c_qs x "
        "that grows with the extension (c_qs > 0 reads long). The motion itself is "
        "unchanged. Its prior, Normal(0, 2) 1/m, allows a 20% error at 0.1 m, the "
        "muscle's whole stroke. In the residual: error proportional to x^2, curving the "
        "static pressure-position map like a quadratic spring of the opposite sign "
        "(length_stiffness), but with no change of the dynamics: the loop's width, the "
        "phase lag and a resonance are read through the same curve, so an experiment "
        "that reaches large x quickly (a fast, wide chirp) tells the two apart where a "
        "slow one cannot."
    )
    physics = staticmethod(_quadratic_sensor)
    inverse = staticmethod(_quadratic_sensor_inverse)

    @classmethod
    def force_rig_priors(cls, stiffness_n_m, amplitude_m, moving_mass_kg):
        """``c_qs`` around a 20% relative error at the motion's amplitude."""
        return {"c_qs": Normal(0.0, 0.2 / amplitude_m)}
