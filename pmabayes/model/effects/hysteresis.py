"""Hysteresis effects: changes of the Bouc-Wen law itself."""

from __future__ import annotations

import math

import numba

from pmabayes.model.effects._numerics import power
from pmabayes.model.effects.base import Effect
from pmabayes.model.parameters import LogNormal, Normal, Parameter

__all__ = ["BoucWenExponent"]


@numba.njit(cache=True, error_model="numpy")
def _bouc_wen_exponent(q, z_abs):
    # |z| (|z| / z_ref)^(n - 1) = |z|^n z_ref^(1 - n): the factor g of c |z| g; the
    # floor keeps g finite at z = 0 for n < 1, where c |z| g vanishes anyway
    y = z_abs / q[1]
    return power(y if y > 1e-6 else 1e-6, q[0] - 1.0)


class BoucWenExponent(Effect):
    """The generalised Bouc-Wen exponent n in |z|^n."""

    name = "bouc_wen_exponent"
    stage = "hysteresis"
    parameters = (
        Parameter(
            "n_bw", "1", 1.0, Normal(1.0, 0.1), bounds=(0.0, math.inf), null=1.0,
            description="Bouc-Wen exponent: dz/dx = alpha - c |z| (|z| / z_ref_bw)^(n_bw "
            "- 1); 1 is the paper's model",
            latex=r"n_\mathrm{BW}",
        ),
        Parameter(
            "z_ref_bw", "N", 10.0, LogNormal(10.0, 1.0), bounds=(0.0, math.inf), vary=False,
            description="hysteretic force at which the generalised law meets the paper's "
            "(a typical |z|)",
            latex=r"z_\mathrm{ref}",
        ),
    )
    description = (
        "The generalised Bouc-Wen law dz/dx = alpha - (beta sgn(dx z) + gamma) |z| "
        "(|z| / z_ref_bw)^(n_bw - 1) changes how sharply the hysteretic force turns "
        "after a reversal: n_bw > 1 keeps z near its initial stiffness longer and bends "
        "later (sharper loop corners), n_bw < 1 bends sooner. In the residual: error at "
        "the corners of each loop, just after every reversal of motion, of opposite "
        "sign on the small and the large loops (the law meets the paper's at |z| = "
        "z_ref_bw), and nearly independent of frequency."
    )
    physics = staticmethod(_bouc_wen_exponent)
