"""Independent high-accuracy reference solver for the PMA / Bouc-Wen model.

This module is the yardstick of the simulator tests. It deliberately shares no
code with :mod:`pmabayes`: it integrates the continuous-time equations of motion

    M x'' + d x' + M g s_g + K_e x + z + F_eff(x, x', p) = A max(p - p_dz, 0)
    z' = x' [alpha - (beta sgn(x' z) + gamma) |z|]

with the classical fourth-order Runge-Kutta method on a fine fixed step
``h = dt / substeps``. The optional effects are written here from their physical
definitions:

* regulator lag: ``p' = (p_cmd(t) - p) / tau_reg``, a fourth state, ``p(0) = p_cmd[0]``;
* transport delay: ``p(t) = p_cmd(t - t_delay)`` with ``p_cmd(t < 0) = p_cmd[0]``;
* second-order regulator: ``tau_n^2 p'' + 2 zeta_reg tau_n p' + p = p_cmd(t)``, a fifth
  state ``p'``, settled at ``p_cmd[0]``;
* Coulomb friction ``F_c tanh(x' / v_c)``, cubic stiffness ``K3 x^3`` and pressure
  stiffness ``K_p p x`` (``p`` the acting pressure);
* Stribeck friction ``[F_k + F_s exp(-(x'/v_s)^2)] tanh(x'/v_st)``;
* McKibben force-length correction ``a_mck ((1 + x/l_0)^2 - 1) max(p - p_mck, 0)``;
* position offset: measured position ``x + x_offset``;
* pressure hysteresis: the force ``kappa_ph (p / p_ref_ph) z``;
* Maxwell creep: a sixth state, the stretch ``u`` of a spring ``k_m`` in series with
  a dashpot ``k_m tau_m``, ``u' = x' - u / tau_m``, ``u(0) = 0``, force ``k_m u``;
* generalised Bouc-Wen exponent: ``z' = x' [alpha - (beta sgn(x' z) + gamma) |z|^n
  z_ref^(1 - n)]``.

The commanded input is a zero-order hold: ``u[k]`` acts on ``[t_k, t_{k+1})``; or a
straight line between samples (``linear``); or any continuous function of time
(``input_fn``, e.g. the exact band-limited signal whose samples ``u`` are), which
every Runge-Kutta stage evaluates at its own time. The
delayed command jumps inside a sample interval; each interval is therefore cut at
that instant into two pieces on which the delayed command is constant, so every
Runge-Kutta stage sees ``p_cmd(t - t_delay)`` exactly and no step straddles a jump.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.optimize import brentq

__all__ = ["ReferenceResult", "reference_simulate", "paper_chirp"]

# Slots of the constants vector passed to the compiled integrator.
(C_MASS, C_AREA, C_F_GRAV, C_ALPHA, C_BETA, C_GAMMA, C_D, C_K_E, C_P_DZ, C_DEAD_ZONE, C_TAU, C_F_C,
 C_V_C, C_K3, C_K_P, C_TAU_N, C_ZETA, C_F_K, C_F_S, C_V_S, C_V_ST, C_A_MCK, C_L_0,
 C_P_MCK, C_KAPPA, C_P_REF, C_K_M, C_TAU_M, C_N_BW, C_Z_REF) = range(30)
N_CONSTANTS = 30
#: x, v, z, acting pressure, its rate (second-order regulator), Maxwell stretch
N_STATES = 6


def paper_chirp(n: int = 15000, dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """The paper's chirp: 0.1 to 3 Hz over 15 s, 0 to 0.5 MPa.

    Returns
    -------
    t, p : numpy.ndarray
        Sample times in s and commanded pressure in Pa.
    """
    t = np.arange(n) * dt
    p = 0.25e6 * (1.0 - np.cos(2.0 * np.pi * (0.1 * t + 2.9 / 30.0 * t**2)))
    return t, p


@numba.njit(cache=True)
def _f_eff(c, x, v, p, z, u):
    """Sum of the force effects at ``(x, v)``, acting pressure ``p``, hysteretic force
    ``z`` and Maxwell stretch ``u``."""
    f = c[C_F_C] * math.tanh(v / c[C_V_C]) + c[C_K3] * x * x * x + c[C_K_P] * p * x
    f += (c[C_F_K] + c[C_F_S] * math.exp(-(v / c[C_V_S]) ** 2)) * math.tanh(v / c[C_V_ST])
    f += c[C_A_MCK] * ((1.0 + x / c[C_L_0]) ** 2 - 1.0) * max(p - c[C_P_MCK], 0.0)
    f += c[C_KAPPA] * p / c[C_P_REF] * z + c[C_K_M] * u
    return f


@numba.njit(cache=True)
def _rhs(c, y, p_cmd):
    """Time derivatives of ``y = (x, v, z, p_act, p_act', u)`` for a constant command."""
    x, v, z, pa, pd, u = y[0], y[1], y[2], y[3], y[4], y[5]
    ddp = 0.0
    if c[C_TAU] > 0.0:
        p = pa
        dpa = (p_cmd - pa) / c[C_TAU]
    elif c[C_TAU_N] > 0.0:
        p = pa
        dpa = pd
        ddp = (p_cmd - pa - 2.0 * c[C_ZETA] * c[C_TAU_N] * pd) / c[C_TAU_N] ** 2
    else:
        p = p_cmd
        dpa = 0.0
    drive = c[C_AREA] * (max(p - c[C_P_DZ], 0.0) if c[C_DEAD_ZONE] > 0.0 else p)
    f_eff = _f_eff(c, x, v, p, z, u)
    acc = (drive - c[C_F_GRAV] - c[C_D] * v - c[C_K_E] * x - z - f_eff) / c[C_MASS]
    sgn = 1.0 if v * z >= 0.0 else -1.0
    n = c[C_N_BW]
    mag = abs(z) if n == 1.0 else abs(z) ** n * c[C_Z_REF] ** (1.0 - n)
    dz = v * (c[C_ALPHA] - (c[C_BETA] * sgn + c[C_GAMMA]) * mag)
    du = v - u / c[C_TAU_M]
    out = np.empty(N_STATES)
    out[0], out[1], out[2], out[3], out[4], out[5] = v, acc, dz, dpa, ddp, du
    return out


@numba.njit(cache=True)
def _rk4_piece(c, y, p_cmd, length, steps):
    """Advance ``y = [x, v, z, p_act]`` in place over ``length`` s in ``steps`` RK4 steps."""
    _rk4_ramp(c, y, p_cmd, p_cmd, length, steps)


@numba.njit(cache=True)
def _rk4_ramp(c, y, a, b, length, steps):
    """Like :func:`_rk4_piece` with the command ramping linearly from ``a`` to ``b``."""
    h = length / steps
    for s in range(steps):
        p0 = a + (b - a) * s / steps
        ph = a + (b - a) * (s + 0.5) / steps
        p1 = a + (b - a) * (s + 1.0) / steps
        k1 = _rhs(c, y, p0)
        k2 = _rhs(c, y + 0.5 * h * k1, ph)
        k3 = _rhs(c, y + 0.5 * h * k2, ph)
        k4 = _rhs(c, y + h * k3, p1)
        for j in range(N_STATES):
            y[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])


@numba.njit(cache=True)
def _integrate_linear(c, u, dt, substeps, x_init, out):
    """:func:`_integrate` for an input that is a straight line between samples."""
    y = np.array([x_init, 0.0, 0.0, u[0], 0.0, 0.0])
    out[:, 0] = y
    for k in range(u.shape[0] - 1):
        _rk4_ramp(c, y, u[k], u[k + 1], dt, substeps)
        out[:, k + 1] = y
        if c[C_TAU] <= 0.0 and c[C_TAU_N] <= 0.0:
            out[3, k + 1] = u[k + 1]


@numba.njit(cache=True)
def _integrate_stages(c, uh, dt, substeps, x_init, out):
    """:func:`_integrate` for an input given at every RK4 stage time: ``uh[q]`` is the
    input at ``q h / 2`` (``h = dt / substeps``)."""
    n = out.shape[1]
    h = dt / substeps
    y = np.array([x_init, 0.0, 0.0, uh[0], 0.0, 0.0])
    out[:, 0] = y
    for k in range(n - 1):
        for s in range(substeps):
            q = 2 * (k * substeps + s)
            k1 = _rhs(c, y, uh[q])
            k2 = _rhs(c, y + 0.5 * h * k1, uh[q + 1])
            k3 = _rhs(c, y + 0.5 * h * k2, uh[q + 1])
            k4 = _rhs(c, y + h * k3, uh[q + 2])
            for j in range(N_STATES):
                y[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        out[:, k + 1] = y
        if c[C_TAU] <= 0.0 and c[C_TAU_N] <= 0.0:
            out[3, k + 1] = uh[2 * (k + 1) * substeps]


@numba.njit(cache=True)
def _integrate(c, u, dt, t_delay, substeps, x_init, out):
    """Integrate a whole trial; ``out[:, k]`` receives (x, v, z, p_act) at ``t_k``."""
    n = u.shape[0]
    shift = int(math.floor(t_delay / dt))  # whole samples of delay
    frac = t_delay / dt - shift  # the delayed command jumps at t_k + frac * dt
    y = np.array([x_init, 0.0, 0.0, u[0], 0.0, 0.0])
    out[:, 0] = y
    for k in range(n - 1):
        # the delayed command is u[k - shift - 1] before the jump, u[k - shift] after
        early = u[max(k - shift - 1, 0)]
        late = u[max(k - shift, 0)]
        if frac > 0.0:
            _rk4_piece(c, y, early, frac * dt, max(1, int(math.ceil(frac * substeps))))
            _rk4_piece(c, y, late, (1.0 - frac) * dt,
                       max(1, int(math.ceil((1.0 - frac) * substeps))))
        else:
            _rk4_piece(c, y, late, dt, substeps)
        out[:, k + 1] = y
        # no regulator state: the acting pressure is the delayed command
        if c[C_TAU] <= 0.0 and c[C_TAU_N] <= 0.0:
            # in force just after t_{k+1}
            out[3, k + 1] = u[max(k + 1 - shift - (1 if frac > 0.0 else 0), 0)]


@dataclass(frozen=True)
class ReferenceResult:
    """States of a reference simulation, each of shape ``(n_samples,)``."""

    position_m: np.ndarray
    true_position_m: np.ndarray
    velocity_m_s: np.ndarray
    hysteresis_n: np.ndarray
    pressure_pa: np.ndarray
    effect_force_n: np.ndarray


def _static_equilibrium(rhs: float, K_e: float, K3: float, K_p: float, p0: float,
                        mck: float = 0.0, l_0: float = 1.0) -> float:
    """Solve ``(K_e + K_p p0) x + K3 x^3 + mck ((1 + x/l_0)^2 - 1) = rhs`` for the
    equilibrium position."""
    k_lin = K_e + K_p * p0
    if K3 == 0.0 and mck == 0.0:
        return rhs / k_lin

    def g(x):
        return k_lin * x + K3 * x**3 + mck * ((1.0 + x / l_0) ** 2 - 1.0) - rhs

    lo, hi = -1e-3, 1e-3
    while g(lo) > 0.0:
        lo *= 2.0
    while g(hi) < 0.0:
        hi *= 2.0
    return brentq(g, lo, hi, xtol=1e-18, rtol=4 * np.finfo(float).eps, maxiter=500)


def reference_simulate(
    u,
    dt: float,
    *,
    mass: float,
    area: float,
    gravity_force: float,
    alpha: float,
    beta: float,
    gamma: float,
    d: float,
    K_e: float,
    p_dz: float = 0.0,
    dead_zone: bool = True,
    tau_reg: float = 0.0,
    t_delay: float = 0.0,
    F_c: float = 0.0,
    v_c: float = 2e-3,
    K3: float = 0.0,
    K_p: float = 0.0,
    x_offset: float = 0.0,
    tau_n: float = 0.0,
    zeta_reg: float = 0.7,
    F_k: float = 0.0,
    F_s: float = 0.0,
    v_s: float = 0.01,
    v_st: float = 2e-3,
    a_mck: float = 0.0,
    l_0: float = 0.17,
    p_mck: float = 66922.0,
    kappa_ph: float = 0.0,
    p_ref_ph: float = 5e5,
    k_m: float = 0.0,
    tau_m: float = 0.2,
    n_bw: float = 1.0,
    z_ref_bw: float = 10.0,
    substeps: int = 64,
    linear: bool = False,
    input_fn=None,
    zero_state: bool = False,
) -> ReferenceResult:
    """Simulate one trial with RK4 on ``substeps`` steps per sample interval.

    Parameters
    ----------
    u : array_like
        Commanded input, ``(n_samples,)``: pressure in Pa (force in N when
        ``dead_zone`` is False), held constant over each sample interval.
    dt : float
        Sample interval in s.
    mass, area, gravity_force : float
        ``M + m`` (kg), ``A`` (m^2; 1 for force input) and ``(M + m) g s_g`` (N).
    alpha, beta, gamma, d, K_e, p_dz : float
        Base parameters (SI units).
    dead_zone : bool
        Apply ``max(p - p_dz, 0)`` (pressure rig); False for a force-driven rig.
    tau_reg, t_delay, F_c, v_c, K3, K_p, x_offset : float
        Effect parameters; 0 switches an effect off.
    tau_n, zeta_reg, F_k, F_s, v_s, v_st, a_mck, l_0, p_mck : float
        Parameters of the second-order regulator (not with ``tau_reg``), the Stribeck
        friction and the McKibben force; ``tau_n``, ``F_k``, ``F_s``, ``a_mck`` = 0
        switch them off.
    kappa_ph, p_ref_ph, k_m, tau_m, n_bw, z_ref_bw : float
        Pressure hysteresis, Maxwell creep and Bouc-Wen exponent; ``kappa_ph = 0``,
        ``k_m = 0`` and ``n_bw = 1`` switch them off.
    substeps : int
        RK4 steps per sample interval.
    linear : bool
        The input is a straight line between samples instead of held (no delay).
    input_fn : callable, optional
        The continuous input: ``input_fn(t)`` for an array of times ``t`` in s (the
        samples ``u[k]`` are at ``t = k dt``) gives the command there; ``u`` then only
        sets the number of samples. With a delay, the command at ``t`` is
        ``input_fn(max(t - t_delay, 0))``.
    zero_state : bool
        Start at ``x = x' = z = 0`` whatever the first input, instead of at rest in
        static equilibrium under it.

    Returns
    -------
    ReferenceResult
        The trial's states at the sample times.
    """
    u = np.ascontiguousarray(u, dtype=float)
    c = np.zeros(N_CONSTANTS)
    c[C_MASS], c[C_AREA], c[C_F_GRAV] = mass, area, gravity_force
    c[C_ALPHA], c[C_BETA], c[C_GAMMA] = alpha, beta, gamma
    c[C_D], c[C_K_E], c[C_P_DZ] = d, K_e, p_dz
    c[C_DEAD_ZONE] = 1.0 if dead_zone else 0.0
    c[C_TAU], c[C_F_C], c[C_V_C], c[C_K3], c[C_K_P] = tau_reg, F_c, v_c, K3, K_p
    if tau_reg > 0.0 and tau_n > 0.0:
        raise ValueError("the reference takes one regulator: tau_reg or tau_n")
    c[C_TAU_N], c[C_ZETA], c[C_F_K], c[C_F_S], c[C_V_S], c[C_V_ST] = (
        tau_n, zeta_reg, F_k, F_s, v_s, v_st)
    c[C_A_MCK], c[C_L_0], c[C_P_MCK] = a_mck, l_0, p_mck
    c[C_KAPPA], c[C_P_REF], c[C_K_M], c[C_TAU_M] = kappa_ph, p_ref_ph, k_m, tau_m
    c[C_N_BW], c[C_Z_REF] = n_bw, z_ref_bw
    if input_fn is not None:
        if linear:
            raise ValueError("give either linear or input_fn")
        times = np.arange((u.shape[0] - 1) * 2 * substeps + 1) * (dt / (2 * substeps))
        uh = np.ascontiguousarray(input_fn(np.maximum(times - t_delay, 0.0)), dtype=float)
        u = uh[:: 2 * substeps]
    p0 = u[0]
    drive0 = area * (max(p0 - p_dz, 0.0) if dead_zone else p0)
    x_init = 0.0 if zero_state else _static_equilibrium(
        drive0 - gravity_force, K_e, K3, K_p, p0, a_mck * max(p0 - p_mck, 0.0), l_0)
    out = np.empty((N_STATES, u.shape[0]))
    if input_fn is not None:
        _integrate_stages(c, uh, float(dt), int(substeps), x_init, out)
    elif linear:
        if t_delay:
            raise ValueError("the reference's linear input takes no transport delay")
        _integrate_linear(c, u, float(dt), int(substeps), x_init, out)
    else:
        _integrate(c, u, float(dt), float(t_delay), int(substeps), x_init, out)
    x, v, z, p, _, stretch = out
    f_eff = np.array([_f_eff(c, x[k], v[k], p[k], z[k], stretch[k]) for k in range(x.size)])
    return ReferenceResult(x + x_offset, x, v, z, p, f_eff)
