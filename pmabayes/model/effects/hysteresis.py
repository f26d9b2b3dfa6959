"""Hysteresis effects: changes of the Bouc-Wen law itself."""

from __future__ import annotations

import math

import numba

from pmabayes.model.effects._numerics import _exp_neg, power
from pmabayes.model.effects.base import Effect
from pmabayes.model.parameters import HalfNormal, LogNormal, Normal, Parameter, Uniform

__all__ = ["BoucWenExponent", "BoucWenBaberNoori"]


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


@numba.njit(cache=True, error_model="numpy")
def _baber_noori(q, z, dx, e):
    # Baber-Noori's dz/dx = h(z) [A(e) alpha - nu(e) c |z|] / eta(e): the factors of
    # alpha and of c |z|, with the slip h = 1 - zeta_s exp(-(z / z_pinch)^2)
    nu = 1.0 + q[0] * e
    eta = 1.0 + q[1] * e
    u = z / q[4]
    h = 1.0 - q[2] * _exp_neg(u * u)
    return h * (1.0 - q[3] * e) / eta, h * nu / eta


@numba.njit(cache=True, error_model="numpy")
def _baber_noori_advance(q, e, z0, z1, dx):
    # the hysteretic energy e = integral of z dx, by the trapezoid over the step (z
    # runs from z0 to z1 under the law; second order, like the step)
    return e + 0.5 * (z0 + z1) * dx


class BoucWenBaberNoori(Effect):
    """Degradation and pinching of the Bouc-Wen law (Baber and Noori)."""

    name = "bouc_wen_baber_noori"
    stage = "hysteresis"
    state = "e_bwbn"
    parameters = (
        Parameter(
            "delta_nu", "1/J", 2.0, HalfNormal(10.0), bounds=(0.0, math.inf), null=0.0,
            description="strength degradation per joule of hysteretic energy e: nu = 1 + "
            "delta_nu e multiplies the saturating term",
            latex=r"\delta_\nu",
        ),
        Parameter(
            "delta_eta", "1/J", 2.0, HalfNormal(10.0), bounds=(0.0, math.inf), null=0.0,
            description="stiffness degradation per joule of hysteretic energy e: the law "
            "is divided by eta = 1 + delta_eta e",
            latex=r"\delta_\eta",
        ),
        Parameter(
            "zeta_s", "1", 0.3, Uniform(0.0, 1.0), bounds=(0.0, 1.0), null=0.0,
            description="pinching severity: the slip h(z) = 1 - zeta_s exp(-(z / "
            "z_pinch)^2) scales the law near z = 0",
            latex=r"\zeta_s",
        ),
        Parameter(
            "delta_a", "1/J", 0.0, HalfNormal(10.0), bounds=(0.0, math.inf), vary=False,
            description="degradation of alpha per joule, A = 1 - delta_a e (fixed at 0: to "
            "first order it is delta_eta's; keep delta_a e < 1)",
            latex=r"\delta_A",
        ),
        Parameter(
            "z_pinch", "N", 5.0, LogNormal(5.0, 1.5), bounds=(0.0, math.inf),
            description="width of the pinched band of the hysteretic force around z = 0; "
            "not tested when there is no pinching (zeta_s = 0)",
            latex=r"z_\mathrm{p}",
        ),
    )
    description = (
        "Baber and Noori's Bouc-Wen law with degradation and pinching (J. Eng. Mech. "
        "111(8), 1985; the BWBN model of Foliente 1995 and Ortiz, Alvarez & Bedoya-Ruiz "
        "2015): dz/dx = h(z) [A(e) alpha - nu(e) (beta sgn(dx z) + gamma) |z|] / "
        "eta(e), with e = integral of z dx the hysteretic energy dissipated since rest "
        "(the law's state e_bwbn, in J), nu = 1 + delta_nu e (strength), eta = 1 + "
        "delta_eta e (stiffness), A = 1 - delta_a e, and the slip h = 1 - zeta_s exp(-(z "
        "/ z_pinch)^2), which softens the law while z passes near zero (pinching, as when "
        "cracks close in reinforced concrete or a braid slips). Pinching is constant "
        "(Baber-Noori's growth of the slip with e and its offset are left out). A "
        "degrading law never reaches a periodic steady state. In the residual: error "
        "that grows cycle after cycle (the model's loops stay as stiff and strong as "
        "the first while the data's shrink) and, with pinching, an S-shaped error at "
        "every zero crossing of z, where the data's loop narrows to a waist."
    )
    physics = staticmethod(_baber_noori)
    advance = staticmethod(_baber_noori_advance)

    @classmethod
    def force_rig_priors(cls, stiffness_n_m, amplitude_m, moving_mass_kg):
        """Degradations per joule around ``1 / (k a^2)`` (unit degradation after the
        energy of a few cycles) and the pinching width around a tenth of the force
        ``k a``."""
        per_joule = 1.0 / (stiffness_n_m * amplitude_m**2)
        return {"delta_nu": HalfNormal(per_joule), "delta_eta": HalfNormal(per_joule),
                "z_pinch": LogNormal(0.1 * stiffness_n_m * amplitude_m, 1.5)}

    @classmethod
    def start_state(cls, *, force_n, motion_m, work_j):
        """The energy dissipated before an estimated start: half-normal on the work the
        record's force does (a record cut from a longer test has degraded by what came
        before it, and restarting it undegraded overpredicts its stiffness and
        strength; on the RC columns' last 30% the energy at the cut, as the fit on the
        first 70% carries it, is 0.1-0.4 of that work)."""
        sigma = max(float(work_j), 1e-300)
        return Parameter(
            "e_bwbn0_j", "J", HalfNormal(sigma).quantile(0.5), HalfNormal(sigma),
            bounds=(0.0, math.inf),
            description="hysteretic energy dissipated before the first sample (the "
            "degradation state e_bwbn there; an estimated start)", latex=r"e_0")
