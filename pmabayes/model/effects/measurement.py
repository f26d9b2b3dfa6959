"""Measurement effects: what the sensor reports of the position."""

from __future__ import annotations

import numba

from pmabayes.model.effects.base import Effect
from pmabayes.model.parameters import Normal, Parameter

__all__ = ["PositionOffset"]


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
