"""Force effects: friction, nonlinear and pressure-dependent stiffness, the McKibben
force, and forces that read the hysteretic force or carry a state of their own.
"""

from __future__ import annotations

import math

import numba

from pmabayes.model.effects._numerics import _exp_neg, decay, smooth_sign
from pmabayes.model.effects.base import Effect
from pmabayes.model.parameters import HalfNormal, LogNormal, Normal, Parameter

__all__ = [
    "CoulombFriction",
    "CubicStiffness",
    "PressureStiffness",
    "StribeckFriction",
    "McKibbenForce",
    "PressureHysteresis",
    "MaxwellCreep",
    "ForceLengthMap",
    "LengthStiffness",
]


@numba.njit(cache=True, error_model="numpy")
def _coulomb_friction(q, x, v, p):
    th = smooth_sign(v / q[1])
    return q[0] * th, 0.0, q[0] * (1.0 - th * th) / q[1]


@numba.njit(cache=True, error_model="numpy")
def _cubic_stiffness(q, x, v, p):
    return q[0] * x * x * x, 3.0 * q[0] * x * x, 0.0


@numba.njit(cache=True, error_model="numpy")
def _pressure_stiffness(q, x, v, p):
    return q[0] * p * x, q[0] * p, 0.0


class CoulombFriction(Effect):
    """Smooth Coulomb friction of the carriage and the braid."""

    name = "coulomb_friction"
    stage = "force"
    parameters = (
        Parameter(
            "F_c", "N", 1.0, HalfNormal(5.0), bounds=(0.0, math.inf), null=0.0,
            description="Coulomb friction force opposing motion (carriage, rail, braid)",
            latex=r"F_\mathrm{c}",
        ),
        Parameter(
            "v_c", "m/s", 2e-3, LogNormal(2e-3, 1.0), bounds=(0.0, math.inf), vary=False,
            description="velocity below which friction is smoothed, F_c tanh(v/v_c); "
            "2 mm/s resolves the switch at 1 kHz",
            latex=r"v_\mathrm{c}",
        ),
    )
    description = (
        "Dry friction on the rail and between braid and bladder resists motion with a "
        "force of nearly constant size F_c, reversing with the direction of motion "
        "(smoothed as F_c tanh(v/v_c)). It widens the hysteresis loop by about 2 F_c / "
        "K_e in position. In the residual: jumps of opposite sign where the velocity "
        "reverses, so the residual correlates with the sign of the velocity."
    )
    physics = staticmethod(_coulomb_friction)


class CubicStiffness(Effect):
    """Stiffness that grows (or softens) with extension."""

    name = "cubic_stiffness"
    stage = "force"
    parameters = (
        Parameter(
            "K3", "N/m^3", 2e4, Normal(0.0, 5e4), null=0.0,
            description="cubic spring coefficient: elastic force K_e x + K3 x^3",
            latex=r"K_3",
        ),
    )
    description = (
        "The bladder stiffens as it stretches, so the elastic force grows faster than "
        "linearly with extension (K3 > 0; K3 < 0 softens). In the residual: error that "
        "depends on position, curving the static pressure-position map at the largest "
        "extensions, and nearly independent of frequency."
    )
    physics = staticmethod(_cubic_stiffness)


class PressureStiffness(Effect):
    """Stiffness that grows with the pressure in the muscle."""

    name = "pressure_stiffness"
    stage = "force"
    parameters = (
        Parameter(
            "K_p", "N/(m Pa)", 3e-4, HalfNormal(1e-3), bounds=(0.0, math.inf), null=0.0,
            description="growth of the stiffness with pressure: K = K_e + K_p p",
            latex=r"K_p",
        ),
    )
    description = (
        "The pressurised braid is stiffer than the empty one: the stiffness rises with "
        "pressure as K_e + K_p p, so the muscle extends less than linearly at high "
        "pressure. In the residual: error proportional to the product of pressure and "
        "position, largest at the peaks of each cycle."
    )
    physics = staticmethod(_pressure_stiffness)


@numba.njit(cache=True, error_model="numpy")
def _stribeck_friction(q, x, v, p):
    # [F_k + F_s exp(-(v/v_s)^2)] tanh(v/v_st), with its exact velocity derivative
    th = smooth_sign(v / q[3])
    r = v / q[2]
    e = _exp_neg(r * r)
    level = q[0] + q[1] * e
    dlevel = -2.0 * q[1] * e * r / q[2]
    return level * th, 0.0, dlevel * th + level * (1.0 - th * th) / q[3]


@numba.njit(cache=True, error_model="numpy")
def _mckibben_force(q, x, v, p):
    # area lost with extension, a_mck ((1 + x/l_0)^2 - 1), times the pressure above
    # the braid's engagement pressure (the force stage sees p before the dead zone)
    pe = p - q[2]
    pe = pe if pe > 0.0 else 0.0
    u = x / q[1]
    return q[0] * pe * u * (2.0 + u), q[0] * pe * 2.0 * (1.0 + u) / q[1], 0.0


class StribeckFriction(Effect):
    """Friction whose static level exceeds the kinetic one (the Stribeck effect)."""

    name = "stribeck_friction"
    stage = "force"
    parameters = (
        Parameter(
            "F_k", "N", 0.5, HalfNormal(5.0), bounds=(0.0, math.inf), null=0.0,
            description="kinetic (sliding) friction force, reached well above the "
            "Stribeck velocity",
            latex=r"F_\mathrm{k}",
        ),
        Parameter(
            "F_s", "N", 0.5, HalfNormal(5.0), bounds=(0.0, math.inf), null=0.0,
            description="static friction in excess of the kinetic: breakaway force "
            "F_k + F_s",
            latex=r"F_\mathrm{s}",
        ),
        Parameter(
            "v_s", "m/s", 0.01, LogNormal(0.01, 1.0), bounds=(0.0, math.inf),
            description="Stribeck velocity over which the static excess decays, "
            "exp(-(v/v_s)^2); not tested when the friction is absent",
            latex=r"v_\mathrm{s}",
        ),
        Parameter(
            "v_st", "m/s", 2e-3, LogNormal(2e-3, 1.0), bounds=(0.0, math.inf), vary=False,
            description="velocity below which the friction's switch is smoothed, "
            "tanh(v/v_st); 2 mm/s resolves it at 1 kHz",
            latex=r"v_\mathrm{st}",
        ),
    )
    description = (
        "Dry friction on the rail and in the braid breaks away at a higher force than it "
        "slides: [F_k + F_s exp(-(v/v_s)^2)] tanh(v/v_st), the static excess F_s decaying "
        "over the Stribeck velocity v_s. It sticks the muscle near each reversal and then "
        "lets it go with a jerk. In the residual: the Coulomb signature (steps of "
        "opposite sign where the velocity reverses, correlation with the sign of the "
        "velocity) with an extra bump just after each reversal, where the velocity is "
        "below v_s, so the residual depends on the speed, not only its sign. With v_s "
        "below the smoothing velocity or F_s = 0 it is Coulomb friction and cannot be "
        "told apart from coulomb_friction."
    )
    physics = staticmethod(_stribeck_friction)


class McKibbenForce(Effect):
    """The McKibben muscle's force per unit pressure falling with extension."""

    name = "mckibben_force"
    stage = "force"
    parameters = (
        Parameter(
            "a_mck", "m^2", 2e-5, HalfNormal(1e-4), bounds=(0.0, math.inf), null=0.0,
            description="area lost per ((1 + x/l_0)^2 - 1) of extension: Chou-Hannaford's "
            "3 l_0^2 / (4 pi n^2) for a braid of n turns",
            latex=r"a_\mathrm{mck}",
        ),
        Parameter(
            "l_0", "m", 0.17, LogNormal(0.17, 0.5), bounds=(0.0, math.inf), vary=False,
            description="unactuated muscle length (the paper's 170 mm)",
            latex=r"l_0",
        ),
        Parameter(
            "p_mck", "Pa", 66922.0, Normal(66922.0, 2e4), vary=False,
            description="pressure at which the bladder engages the braid; set it to the "
            "model's p_dz (the paper's 66 922 Pa by default)",
            latex=r"p_\mathrm{mck}",
        ),
    )
    description = (
        "Chou and Hannaford's force-length law of the braided (McKibben) muscle, F = "
        "(pi D_0^2 / 4) p (3 cos^2 theta - 1) with cos theta = L / b (IEEE Trans. Robot. "
        "Autom. 12(1), 1996): for this extending muscle the push per unit pressure falls "
        "as the braid angle closes with the length L = l_0 + x, quadratically, so the "
        "constant area A becomes A - a_mck ((1 + x/l_0)^2 - 1). The lost force, a_mck "
        "((1 + x/l_0)^2 - 1) max(p - p_mck, 0), opposes extension. In the residual: the "
        "model overshoots the largest extensions at high pressure, by an error growing "
        "with pressure times position and curving upward with position (unlike "
        "pressure_stiffness, which is linear in position), and absent below the dead zone."
    )
    physics = staticmethod(_mckibben_force)


@numba.njit(cache=True, error_model="numpy")
def _pressure_hysteresis(q, x, v, p, z, s):
    w = q[0] * p / q[1]
    return w * z, 0.0, 0.0, w, 0.0


@numba.njit(cache=True, error_model="numpy")
def _maxwell_creep(q, x, v, p, z, u):
    return q[0] * u, 0.0, 0.0, 0.0, q[0]


@numba.njit(cache=True, error_model="numpy")
def _maxwell_creep_advance(q, u, x0, x1, h):
    # the dashpot's stretch u = x - y obeys u' = x' - u / tau; with x' constant over
    # the step the solution is exact, and linear in x1
    e, phi = decay(h / q[1])
    return u * e + (x1 - x0) * phi, phi


class PressureHysteresis(Effect):
    """Hysteretic force that grows with pressure (braid-bladder friction)."""

    name = "pressure_hysteresis"
    stage = "force"
    reads_z = True
    parameters = (
        Parameter(
            "kappa_ph", "1", 0.3, HalfNormal(1.0), bounds=(0.0, math.inf), null=0.0,
            description="growth of the hysteretic force with pressure: z (1 + kappa_ph "
            "p / p_ref_ph)",
            latex=r"\kappa_\mathrm{ph}",
        ),
        Parameter(
            "p_ref_ph", "Pa", 5e5, LogNormal(5e5, 1.0), bounds=(0.0, math.inf), vary=False,
            description="reference pressure of the pressure-dependent hysteresis (the "
            "chirp's peak)",
            latex=r"p_\mathrm{ref}",
        ),
    )
    description = (
        "The braid's fibres press on the bladder harder as the pressure rises, so the "
        "friction between them, and with it the hysteretic force, grows with pressure: "
        "the force z becomes z (1 + kappa_ph p / p_ref_ph). The loop is narrow at low "
        "pressure and wide at high pressure. In the residual: error proportional to the "
        "product of pressure and the hysteretic force, so it changes sign at each "
        "reversal of motion and is largest at the pressure peaks, where the model's loop "
        "is too narrow; unlike pressure_stiffness it does not follow the position."
    )
    physics = staticmethod(_pressure_hysteresis)


class MaxwellCreep(Effect):
    """A spring and a dashpot in series, beside the muscle: viscoelastic creep."""

    name = "maxwell_creep"
    stage = "force"
    state = "u_m"
    parameters = (
        Parameter(
            "k_m", "N/m", 200.0, HalfNormal(500.0), bounds=(0.0, math.inf), null=0.0,
            description="stiffness of the creep element's spring (in series with its "
            "dashpot, the pair beside the muscle)",
            latex=r"k_\mathrm{m}",
        ),
        Parameter(
            "tau_m", "s", 0.2, LogNormal(0.2, 1.0), bounds=(0.0, math.inf), vary=False,
            description="relaxation time c_m / k_m of the creep element (fixed by "
            "default: at k_m = 0 the data cannot say it; free it to identify it)",
            latex=r"\tau_\mathrm{m}",
        ),
    )
    description = (
        "The silicone bladder is viscoelastic: besides its spring it holds a spring k_m "
        "in series with a dashpot c_m = k_m tau_m (a Maxwell element), whose stretch "
        "u_m relaxes with time constant tau_m, so the muscle creeps on after a step and "
        "is stiffer by up to k_m when it moves faster than 1 / tau_m. In the residual: "
        "error that follows a low-passed velocity (the position's recent change), a "
        "slow drift after each fast move, and a stiffness that rises with the chirp's "
        "frequency past 1 / (2 pi tau_m)."
    )
    physics = staticmethod(_maxwell_creep)
    advance = staticmethod(_maxwell_creep_advance)

    @classmethod
    def start_state(cls, *, force_n, motion_m, work_j):
        """The dashpot's stretch at an estimated start: normal about 0 (relaxed) with
        the record's motion as its spread."""
        sd = max(float(motion_m), 1e-300)
        return Parameter(
            "u_m0_m", "m", 0.0, Normal(0.0, sd), bounds=(-1e3 * sd, 1e3 * sd),
            description="stretch of the creep element's dashpot at the first sample (its "
            "state u_m there; an estimated start)", latex=r"u_{\mathrm{m},0}")


@numba.njit(cache=True, error_model="numpy")
def _force_length_map(q, x, v, p):
    # the push lost per unit pressure, a quadratic in the absolute strain u = x / l_fl
    u = x / q[2]
    return p * u * (q[0] + q[1] * u), p * (q[0] + 2.0 * q[1] * u) / q[2], 0.0


@numba.njit(cache=True, error_model="numpy")
def _length_stiffness(q, x, v, p, z, s):
    # tangent stiffness K_e + K_L x, and the hysteretic force z (1 + kappa_L x)
    return (0.5 * q[0] * x * x + q[1] * x * z, q[0] * x + q[1] * z, 0.0, q[1] * x, 0.0)


class ForceLengthMap(Effect):
    """The static force-length-pressure map of the muscle, in its absolute length."""

    name = "force_length_map"
    stage = "force"
    parameters = (
        Parameter(
            "a1_fl", "m^2", 2e-5, Normal(0.0, 1e-4), null=0.0,
            description="effective area lost per unit of absolute strain x / l_fl: the "
            "push is p (A - a1_fl u - a2_fl u^2); Tondu-Lopez's 2 k A'",
            latex=r"a_{1}",
        ),
        Parameter(
            "a2_fl", "m^2", -1e-5, Normal(0.0, 1e-4), null=0.0,
            description="effective area lost per squared strain (the map's curvature); "
            "Tondu-Lopez's -k^2 A', Chou-Hannaford's +a1_fl / 2 for an extending braid",
            latex=r"a_{2}",
        ),
        Parameter(
            "l_fl", "m", 0.17, LogNormal(0.17, 0.5), bounds=(0.0, math.inf), vary=False,
            description="the muscle's length at x = 0 (unloaded, unpressurised): the "
            "strain's reference (the paper's 170 mm; set it to your muscle's)",
            latex=r"l_\mathrm{fl}",
        ),
    )
    description = (
        "The force of a fluidic muscle depends on its length as well as its pressure: "
        "Tondu and Lopez's F = A' p [(1 - k eps)^2 - b] for a contracting muscle (IEEE "
        "Control Syst. Mag. 20(2), 2000), Chou and Hannaford's for a braid. Written about "
        "the model's x = 0 (the unloaded length l_fl, so u = x / l_fl is the absolute "
        "strain, positive in the direction the pressure drives), the push A p loses p "
        "(a1_fl u + a2_fl u^2), a smooth quadratic that holds both laws. Each experiment "
        "starts at rest where the map balances its own dead load (the rig's moving mass, "
        "gravity known), so a heavier load sits at another strain, where the force per "
        "pressure and the pressure's stiffness p (a1_fl + 2 a2_fl u) / l_fl differ: the "
        "same pressure moves each load by a different amount although each record is "
        "zeroed at its start. In the residual: a gain error that grows with pressure "
        "and changes sign and size with the load (the experiments disagree on K_e and "
        "A), curving with position at the pressure peaks; on one load its linear part "
        "is pressure_stiffness's p x signature."
    )
    physics = staticmethod(_force_length_map)


class LengthStiffness(Effect):
    """Stiffness and hysteresis that change with the absolute length (the operating point)."""

    name = "length_stiffness"
    stage = "force"
    reads_z = True
    parameters = (
        Parameter(
            "K_L", "N/m^2", 2e3, Normal(0.0, 1e4), null=0.0,
            description="growth of the tangent stiffness with the absolute position: K = "
            "K_e + K_L x (force K_e x + K_L x^2 / 2)",
            latex=r"K_L",
        ),
        Parameter(
            "kappa_L", "1/m", 2.0, Normal(0.0, 10.0), null=0.0,
            description="growth of the hysteretic force with the absolute position: z "
            "(1 + kappa_L x)",
            latex=r"\kappa_L",
        ),
    )
    description = (
        "The stiffness and the hysteresis of the muscle change with its operating point: "
        "a coiled or braided tube stiffens as it is stretched, and its internal friction "
        "changes with the strain. The tangent stiffness becomes K_e + K_L x and the "
        "hysteretic force z (1 + kappa_L x), with x the absolute position (from the "
        "unloaded length). A dead load sets the operating point: under m g the muscle "
        "rests near x = -m g / K_e, so each load sees its own stiffness and loop width "
        "although each record is zeroed at its start; the pressure's part of the same "
        "dependence is pressure_stiffness and pressure_hysteresis. In the residual: "
        "error proportional to x^2 and to x z, so a fit of several loads together "
        "leaves the light loads' motion too small and the heavy loads' too large (or the "
        "reverse), and fitted one load at a time K_e and alpha move with the load."
    )
    physics = staticmethod(_length_stiffness)

    @classmethod
    def force_rig_priors(cls, stiffness_n_m, amplitude_m, moving_mass_kg):
        """``K_L`` around the stiffness per amplitude, ``kappa_L`` around one per
        amplitude: a change of order one over the motion."""
        return {"K_L": Normal(0.0, stiffness_n_m / amplitude_m),
                "kappa_L": Normal(0.0, 1.0 / amplitude_m)}
