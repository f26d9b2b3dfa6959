"""A model along a trajectory, linearised: its force effects and their derivatives, and
the linear time-varying system of the whole plant (:func:`linearise`).

The one place outside the simulator that evaluates the force effects' ``physics`` and
``advance``, whatever their signature (plain, reading ``z``, carrying a state), and the
Bouc-Wen law (:func:`pmabayes.model.boucwen.linearised`) with its hysteresis effect:
callers (the discrepancy step's linear response) ask this module instead of calling an
effect themselves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmabayes.model import boucwen
from pmabayes.model.boucwen import BoucWenColumns
from pmabayes.model.model import Model

__all__ = ["LinearisationError", "EffectForces", "Linearisation", "effect_forces", "linearise"]


class LinearisationError(ValueError):
    """A model holds something the linearisation does not follow (a hysteresis law
    with a state): what needs it (the discrepancy step) is skipped, and says why."""

#: Relative step of the central differences taken of ``advance`` (in the state and the
#: start position) and of a hysteresis effect's factor ``g(|z|)``: these give no
#: derivative of their own, and are smooth where they are differenced.
_FD_STEP = 1e-6


@dataclass(frozen=True)
class EffectForces:
    """The sum of a model's force effects along a trajectory, with its derivatives.

    Each array is ``(n_samples,)`` unless said otherwise; the derivatives are partial
    (a stateful effect's state held), its dependence on the motion is in ``state_*``.

    Attributes
    ----------
    force_n : numpy.ndarray
        Sum of the force effects (opposing extension).
    dforce_dx, dforce_dv, dforce_dz : numpy.ndarray
        Its derivatives in position (N/m), velocity (N s/m) and the hysteretic force
        ``z`` (1; nonzero only for effects that read ``z``).
    state_names : tuple of str
        The stateful effects' states, in the model's order of effects.
    states : numpy.ndarray
        ``(n_states, n_samples)``: each state along the trajectory, advanced with its
        effect's ``advance`` from 0 (the rest state) at the first sample.
    dforce_dstate : numpy.ndarray
        ``(n_states, n_samples)``: the force's derivative in each state.
    state_rate : numpy.ndarray
        ``(n_states, n_samples, 3)``: the linearised rate of each state,
        ``ds' = rate[0] ds + rate[1] dx + rate[2] dv``, over the sample interval that
        starts at each sample (the last repeats the one before).
    """

    force_n: np.ndarray
    dforce_dx: np.ndarray
    dforce_dv: np.ndarray
    dforce_dz: np.ndarray
    state_names: tuple[str, ...]
    states: np.ndarray
    dforce_dstate: np.ndarray
    state_rate: np.ndarray


@dataclass(frozen=True)
class Linearisation:
    """The plant linearised along a trajectory: ``dy' = A[k] dy + b f`` for the
    perturbation ``dy = (dx, dv, dz, d states...)`` by an extra force ``f`` opposing
    extension.

    Attributes
    ----------
    mass_kg : float
        The moving mass.
    a : numpy.ndarray
        ``(n_samples, n_rows, n_rows)``: the system matrix at each sample.
    b : numpy.ndarray
        ``(n_rows,)``: where an extra force enters (``-1 / mass`` in the velocity's row).
    rest : numpy.ndarray
        ``(n_rows,)``: the static change of the state per newton of force held at rest
        (the position's ``-1 / stiffness``, ``z`` unchanged, states settled).
    forces : EffectForces
        The force effects along the trajectory.
    dt_s : float
        The trajectory's sample interval.
    """

    mass_kg: float
    a: np.ndarray
    b: np.ndarray
    rest: np.ndarray
    forces: EffectForces
    dt_s: float


def _flat(*arrays) -> tuple[np.ndarray, ...]:
    """Each array as a 1-D float array (a member's parameters, a trajectory)."""
    return tuple(np.asarray(a, dtype=float).reshape(-1) for a in arrays)


def _phis(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(e^y - 1) / y`` and ``(e^y - 1 - y) / y^2``, without cancellation near 0."""
    y = np.asarray(y, dtype=float)
    small = np.abs(y) < 1e-3
    ys = np.where(small, 1.0, y)
    p1 = np.where(small, 1.0 + y / 2 + y * y / 6 + y**3 / 24, np.expm1(ys) / ys)
    p2 = np.where(small, 0.5 + y / 6 + y * y / 24 + y**3 / 120, (np.expm1(ys) - ys) / ys**2)
    return p1, p2


def _state_along(eff, q: np.ndarray, x: np.ndarray, dt_s: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A stateful effect's state along ``x`` from 0 at the first sample, and its
    linearised rate ``(n, 3)`` (state, position, velocity) over each sample interval.

    Over one interval of ``h = dt_s`` the exact step ``s1 = advance(s0, x0, x1)`` of a
    linear rate ``s' = lam s + nu x + mu v`` with ``x`` linear in time has the
    derivatives ``a = e^(lam h)``, ``b0 + b1 = nu h phi1`` and ``b1 = nu h phi2 + mu
    phi1`` (``phi1``, ``phi2`` of ``lam h``, :func:`_phis`); these are solved for the
    rate from ``advance``'s own ``b1`` and central differences for ``a`` and ``b0``.
    """
    n = x.size
    s = np.zeros(n)
    b1 = np.zeros(n)
    for k in range(n - 1):
        r = eff.advance(q, s[k], x[k], x[k + 1], dt_s)
        s[k + 1], b1[k] = r[0], r[1]
    ds = _FD_STEP * max(float(np.max(np.abs(s))), float(np.ptp(x)), 1e-12)
    dx = _FD_STEP * max(float(np.ptp(x)), 1e-12)
    a, b0 = np.ones(n), np.zeros(n)
    for k in range(n - 1):
        a[k] = (eff.advance(q, s[k] + ds, x[k], x[k + 1], dt_s)[0]
                - eff.advance(q, s[k] - ds, x[k], x[k + 1], dt_s)[0]) / (2 * ds)
        b0[k] = (eff.advance(q, s[k], x[k] + dx, x[k + 1], dt_s)[0]
                 - eff.advance(q, s[k], x[k] - dx, x[k + 1], dt_s)[0]) / (2 * dx)
    if n > 1:
        a[-1], b0[-1], b1[-1] = a[-2], b0[-2], b1[-2]
    if np.any(a <= 0.0) or not np.all(np.isfinite(a)):
        raise ValueError(f"effect {eff.name!r}: its state's step over {dt_s:g} s does not "
                         "decay as a linear rate's would (d new_state / d state <= 0 or not "
                         "finite); the linearisation cannot be taken")
    lam = np.log(a) / dt_s
    p1, p2 = _phis(lam * dt_s)
    nu = (b0 + b1) / (dt_s * p1)
    mu = (b1 - nu * dt_s * p2) / p1
    return s, np.stack([lam, nu, mu], axis=1)


def effect_forces(model: Model, theta: np.ndarray, x_m: np.ndarray, v_m_s: np.ndarray,
                  p_pa: np.ndarray, z_n: np.ndarray, dt_s: float) -> EffectForces:
    """A model's force effects along a trajectory, with their derivatives.

    Plain effects get ``(x, v, p)``; effects that read ``z`` or carry a state get the
    extended signature, the state advanced along the trajectory from 0 (the rest state)
    at the first sample with the effect's ``advance``.

    Parameters
    ----------
    model : Model
        The model.
    theta : numpy.ndarray
        One member's parameters, ``(n_parameters,)`` (or ``(1, n_parameters)``).
    x_m, v_m_s, p_pa, z_n : numpy.ndarray
        Position (before measurement effects), velocity, the input acting on the
        actuator (after pressure effects) and the hysteretic force, ``(n_samples,)``.
    dt_s : float
        Sample interval.

    Returns
    -------
    EffectForces
    """
    th, x, v, p, z = _flat(theta, x_m, v_m_s, p_pa, z_n)
    n = x.size
    out = {k: np.zeros(n) for k in ("f", "fx", "fv", "fz")}
    names, states, dstate, rates = [], [], [], []
    for eff, sl in model.effect_slices():
        if eff.stage != "force":
            continue
        q = np.ascontiguousarray(th[sl])
        s = np.zeros(n)
        if eff.state is not None:
            s, rate = _state_along(eff, q, x, dt_s)
            names.append(eff.state)
            states.append(s)
            rates.append(rate)
        fs = np.zeros(n)
        for k in range(n):
            if eff.extended():
                r = eff.physics(q, x[k], v[k], p[k], z[k], s[k])
                out["fz"][k] += r[3]
                fs[k] = r[4]
            else:
                r = eff.physics(q, x[k], v[k], p[k])
            out["f"][k] += r[0]
            out["fx"][k] += r[1]
            out["fv"][k] += r[2]
        if eff.state is not None:
            dstate.append(fs)
    m = len(names)
    return EffectForces(out["f"], out["fx"], out["fv"], out["fz"], tuple(names),
                        np.array(states).reshape(m, n), np.array(dstate).reshape(m, n),
                        np.array(rates).reshape(m, n, 3))


def _hysteresis_rates(model: Model, th: np.ndarray, v: np.ndarray, z: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The Bouc-Wen law ``z' = (alpha - c g(|z|) |z|) v`` linearised, ``dz' = kz dv +
    bz dz``, with the hysteresis effect's factor ``g`` (1 without one)."""
    az = np.abs(z)
    g, dg = np.ones_like(z), np.zeros_like(z)
    for eff, sl in model.effect_slices():
        if eff.stage == "hysteresis":  # at most one
            if eff.state is not None:
                raise LinearisationError(
                    f"the hysteresis law {eff.name!r} carries a state ({eff.state!r}), "
                    "which the linearisation does not follow yet: diagnose the model "
                    "without it, or without the discrepancy step")
            q = np.ascontiguousarray(th[sl])
            h = _FD_STEP * max(float(np.max(az)), 1e-12)
            for k in range(z.size):
                g[k] = eff.physics(q, az[k])
                lo = max(az[k] - h, 0.0)
                dg[k] = (eff.physics(q, az[k] + h) - eff.physics(q, lo)) / (az[k] + h - lo)
    return boucwen.linearised(v, z, *BoucWenColumns.of(model).law(th), g, dg)


def linearise(model: Model, theta: np.ndarray, x_m: np.ndarray, v_m_s: np.ndarray,
              p_pa: np.ndarray, z_n: np.ndarray, dt_s: float) -> Linearisation:
    """The plant linearised along a trajectory (a simulation's recorded states).

    The equation of motion ``m x'' = F(p) - K_e x - d v - z - sum of force effects``,
    the Bouc-Wen law with its hysteresis effect, and each stateful force effect's
    state, all to first order about the trajectory.

    Parameters
    ----------
    model, theta : Model, numpy.ndarray
        The model and one member's parameters, as for :func:`effect_forces`.
    x_m, v_m_s, p_pa, z_n : numpy.ndarray
        The trajectory, as in :func:`effect_forces`.
    dt_s : float
        Sample interval.

    Returns
    -------
    Linearisation
    """
    th, x, v, p, z = _flat(theta, x_m, v_m_s, p_pa, z_n)
    ef = effect_forces(model, th, x, v, p, z, dt_s)
    rig = model.rig_columns
    mass = float(th[rig["moving_mass_kg"]] if "moving_mass_kg" in rig
                 else model.rig.moving_mass_kg)
    kz, bz = _hysteresis_rates(model, th, v, z)
    m = len(ef.state_names)
    rows = 3 + m
    a = np.zeros((x.size, rows, rows))
    a[:, 0, 1] = 1.0
    a[:, 1, 0] = -(th[model.index("K_e")] + ef.dforce_dx) / mass
    a[:, 1, 1] = -(th[model.index("d")] + ef.dforce_dv) / mass
    a[:, 1, 2] = -(1.0 + ef.dforce_dz) / mass
    a[:, 2, 1] = kz
    a[:, 2, 2] = bz
    for j in range(m):
        a[:, 1, 3 + j] = -ef.dforce_dstate[j] / mass
        a[:, 3 + j, 3 + j] = ef.state_rate[j, :, 0]
        a[:, 3 + j, 0] = ef.state_rate[j, :, 1]
        a[:, 3 + j, 1] = ef.state_rate[j, :, 2]
    b = np.zeros(rows)
    b[1] = -1.0 / mass
    # at rest (v = 0, z held) each state settles where its rate vanishes
    lam, nu = ef.state_rate[:, 0, 0], ef.state_rate[:, 0, 1]
    settle = np.where(lam != 0.0, -nu / np.where(lam != 0.0, lam, 1.0), 0.0)
    stiff = (th[model.index("K_e")] + ef.dforce_dx[0]
             + float(np.sum(ef.dforce_dstate[:, 0] * settle)))
    rest = np.zeros(rows)
    rest[0] = -1.0 / stiff
    rest[3:] = settle * rest[0]
    return Linearisation(mass, a, b, rest, ef, float(dt_s))
