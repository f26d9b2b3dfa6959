"""Effects on the pressure path, before the dead zone: regulator lags and transport delay."""

from __future__ import annotations

import math

import numba
import numpy as np

from pmabayes.model.effects.base import Effect
from pmabayes.model.parameters import LogNormal, Parameter

__all__ = ["RegulatorLag", "TransportDelay", "RegulatorSecondOrder", "delay_effect"]


@numba.njit(cache=True, error_model="numpy")
def _regulator_lag(q, p_start, p_end, dt_s):
    # Exact response of the lag to each linear input piece, projected back onto one
    # linear piece per interval (matching mean and first moment), so that tau -> 0
    # recovers the held input and the output stays smooth in tau.
    n, batch = p_start.shape
    e_h = np.empty(batch)
    inv_h = np.empty(batch)
    m0 = np.empty(batch)
    m1 = np.empty(batch)
    y = np.empty(batch)
    for i in range(batch):
        h = dt_s / max(q[i, 0], 1e-300)
        e_h[i] = math.exp(-h)
        inv_h[i] = 1.0 / h
        m0[i] = -math.expm1(-h) / h  # mean of exp(-h t) on [0, 1]
        m1[i] = (-math.expm1(-h) - h * e_h[i]) / (h * h)  # first moment of exp(-h t)
        y[i] = p_start[0, i]  # the regulator starts settled at the first command
    for k in range(n):
        for i in range(batch):
            a = p_start[k, i]
            slope = p_end[k, i] - a
            ramp = slope * inv_h[i]
            c = y[i] - a + ramp
            mean = a + 0.5 * slope - ramp + c * m0[i]
            moment = 0.5 * a + slope / 3.0 - 0.5 * ramp + c * m1[i]
            y[i] = p_end[k, i] - ramp + c * e_h[i]
            p_start[k, i] = 4.0 * mean - 6.0 * moment
            p_end[k, i] = 6.0 * moment - 2.0 * mean


@numba.njit(cache=True, error_model="numpy")
def _delay_moments(f, a0, b0, a1, b1):
    # mean and first moment over one interval of a piecewise-linear signal whose
    # previous piece (a0 -> b0) fills the first f of it and whose next piece
    # (a1 -> b1) fills the rest
    g = 1.0 - f
    s0 = b0 - a0
    s1 = b1 - a1
    mean = f * a0 + s0 * (g * f + 0.5 * f * f) + g * a1 + 0.5 * s1 * g * g
    moment = (
        (a0 + s0 * g) * 0.5 * f * f
        + s0 * f * f * f / 3.0
        + (a1 - s1 * f) * 0.5 * (1.0 - f * f)
        + s1 * (1.0 - f * f * f) / 3.0
    )
    return mean, moment


@numba.njit(cache=True, error_model="numpy")
def _transport_delay(q, p_start, p_end, dt_s):
    # Project the delayed piecewise-linear signal back onto one linear piece per
    # interval, matching its mean and first moment: exact for linear input and
    # continuous in the delay, so the likelihood stays smooth in t_delay.
    n_samples, batch = p_start.shape
    shift = np.empty(batch, dtype=np.int64)
    w = np.empty((8, batch))  # start and end as linear maps of (a0, b0, a1, b1)
    unit = np.eye(4)
    for i in range(batch):
        s = max(q[i, 0], 0.0) / dt_s
        shift[i] = int(math.floor(s))
        for j in range(4):
            mean, moment = _delay_moments(s - shift[i], unit[j, 0], unit[j, 1], unit[j, 2],
                                          unit[j, 3])
            w[j, i] = 4.0 * mean - 6.0 * moment
            w[4 + j, i] = 6.0 * moment - 2.0 * mean
    rest = p_start[0].copy()  # before the trial the pressure rests at its first value
    for k in range(n_samples - 1, -1, -1):  # backwards: reads only earlier samples
        for i in range(batch):
            j0 = k - shift[i] - 1
            j0c = j0 if j0 > 0 else 0
            j1c = j0 + 1 if j0 + 1 > 0 else 0
            a0 = p_start[j0c, i] if j0 >= 0 else rest[i]
            b0 = p_end[j0c, i] if j0 >= 0 else rest[i]
            a1 = p_start[j1c, i] if j0 >= -1 else rest[i]
            b1 = p_end[j1c, i] if j0 >= -1 else rest[i]
            p_start[k, i] = w[0, i] * a0 + w[1, i] * b0 + w[2, i] * a1 + w[3, i] * b1
            p_end[k, i] = w[4, i] * a0 + w[5, i] * b0 + w[6, i] * a1 + w[7, i] * b1


class RegulatorLag(Effect):
    """First-order lag of the pressure regulator."""

    name = "regulator_lag"
    stage = "pressure"
    parameters = (
        Parameter(
            "tau_reg", "s", 0.04, LogNormal(0.03, 1.0), bounds=(0.0, math.inf), null=0.0,
            description="time constant of the first-order lag between commanded and "
            "actual pressure",
            latex=r"\tau_\mathrm{reg}",
        ),
    )
    description = (
        "The proportional regulator and the tubing fill the muscle through a first-order "
        "lag: the pressure that acts trails the command by tau_reg and its swings shrink "
        "as frequency rises. In the residual: error that grows with the chirp's "
        "frequency, and a response that lags the pressure (the residual correlates with "
        "the input's rate of change)."
    )
    physics = staticmethod(_regulator_lag)

    @classmethod
    def history_s(cls, q: np.ndarray) -> np.ndarray:
        """``40 tau_reg``: exp(-40) of the older past remains (see :meth:`Effect.history_s`)."""
        return 40.0 * q[:, 0]

    @classmethod
    def lead_s(cls, q: np.ndarray) -> np.ndarray:
        """``tau_reg``: the first-order lead ``1 + tau s ~ exp(tau s)`` (:meth:`Effect.lead_s`)."""
        return q[:, 0]


class TransportDelay(Effect):
    """Dead time between the pressure command and the actuator."""

    name = "transport_delay"
    stage = "pressure"
    parameters = (
        Parameter(
            "t_delay", "s", 0.02, LogNormal(0.02, 1.0), bounds=(0.0, math.inf), null=0.0,
            description="dead time between commanded and actual pressure (valve, tubing)",
            latex=r"T_\mathrm{d}",
        ),
    )
    description = (
        "The pressure wave needs time to travel down the tubing and the valve to react, "
        "so the actuator sees the command t_delay late. Unlike a lag it shifts phase in "
        "proportion to frequency without shrinking the amplitude. In the residual: error "
        "proportional to the rate of change of the response, growing linearly with "
        "frequency, and a peak of the input-residual cross-correlation at a positive lag."
    )
    physics = staticmethod(_transport_delay)

    @classmethod
    def history_s(cls, q: np.ndarray) -> np.ndarray:
        """``t_delay`` (see :meth:`Effect.history_s`)."""
        return np.maximum(q[:, 0], 0.0)

    @classmethod
    def lead_s(cls, q: np.ndarray) -> np.ndarray:
        """``t_delay``: predicting that far ahead is exact in phase (see :meth:`Effect.lead_s`)."""
        return q[:, 0]

    @classmethod
    def add_delay(cls, q: np.ndarray, delay_s: float) -> np.ndarray:
        """``t_delay + delay_s`` (see :meth:`Effect.add_delay`)."""
        out = np.array(q, dtype=float, copy=True)
        out[:, 0] += delay_s
        return out


@numba.njit(cache=True, error_model="numpy")
def _second_order_transition(tn, zeta):
    """Homogeneous solution of ``tn^2 e'' + 2 zeta tn e' + e = 0`` over unit time.

    Returns ``(phi0, phi1, dphi0, dphi1)``: ``e(1) = phi0 e(0) + phi1 e'(0)`` and
    ``e'(1) = dphi0 e(0) + dphi1 e'(0)``, for any ``tn > 0``, ``zeta > 0``, free of
    overflow and of cancellation near critical damping.
    """
    m = -zeta / tn  # mean of the two roots
    w = (zeta * zeta - 1.0) / (tn * tn)  # their half-difference squared
    if w > 1.0:  # well separated real roots: the eigen form, stable for stiff roots
        s = math.sqrt(zeta * zeta - 1.0)
        l1 = -1.0 / (tn * (zeta + s))  # the slow root, without cancellation
        l2 = -(zeta + s) / tn
        e1 = math.exp(l1)
        e2 = math.exp(l2)
        den = l1 - l2
        phi1 = (e1 - e2) / den
        phi0 = (l1 * e2 - l2 * e1) / den
        dphi1 = (l1 * e1 - l2 * e2) / den
    else:  # close or complex roots: cosh / sinh(x)/x of sqrt(w), entire in w
        em = math.exp(m)
        if w > 0.0:
            r = math.sqrt(w)
            c, sc = math.cosh(r), math.sinh(r) / r
        elif w < 0.0:
            r = math.sqrt(-w)
            c, sc = math.cos(r), math.sin(r) / r
        else:
            c, sc = 1.0, 1.0
        phi1 = em * sc
        phi0 = em * (c - m * sc)
        dphi1 = em * (c + m * sc)
    dphi0 = -phi1 / (tn * tn)
    return phi0, phi1, dphi0, dphi1


@numba.njit(cache=True, error_model="numpy")
def _regulator_second_order(q, p_start, p_end, dt_s):
    # Exact response of tau_n^2 y'' + 2 zeta tau_n y' + y = u to each linear input
    # piece, projected back onto one linear piece per interval (matching mean and first
    # moment) as for the first-order lag; tau_n -> 0 recovers the input. Time is in
    # units of the interval; the moments follow from the end values through the ODE.
    n, batch = p_start.shape
    co = np.empty((7, batch))
    y = np.empty(batch)
    yd = np.zeros(batch)  # dy/d(t/dt): the regulator starts settled at the first command
    for i in range(batch):
        tn = max(q[i, 0] / dt_s, 1e-100)
        phi0, phi1, dphi0, dphi1 = _second_order_transition(tn, q[i, 1])
        co[0, i], co[1, i], co[2, i], co[3, i] = phi0, phi1, dphi0, dphi1
        co[4, i] = tn * tn
        co[5, i] = 2.0 * q[i, 1] * tn
        y[i] = p_start[0, i]
    for k in range(n):
        for i in range(batch):
            a = p_start[k, i]
            slope = p_end[k, i] - a
            lag = co[5, i] * slope  # the particular solution is u - 2 zeta tau_n u'
            e0 = y[i] - a + lag
            d0 = yd[i] - slope
            e1 = co[0, i] * e0 + co[1, i] * d0
            d1 = co[2, i] * e0 + co[3, i] * d0
            m0 = -co[4, i] * (d1 - d0) - co[5, i] * (e1 - e0)
            m1 = -co[4, i] * (d1 - e1 + e0) - co[5, i] * (e1 - m0)
            mean = a + 0.5 * slope - lag + m0
            moment = 0.5 * a + slope / 3.0 - 0.5 * lag + m1
            y[i] = a + slope - lag + e1
            yd[i] = slope + d1
            p_start[k, i] = 4.0 * mean - 6.0 * moment
            p_end[k, i] = 6.0 * moment - 2.0 * mean


class RegulatorSecondOrder(Effect):
    """Second-order (possibly ringing) pressure regulator."""

    name = "regulator_second_order"
    stage = "pressure"
    parameters = (
        Parameter(
            "tau_n", "s", 0.01, LogNormal(0.01, 1.0), bounds=(0.0, math.inf), null=0.0,
            description="inverse natural frequency 1/omega_n of the regulator's "
            "second-order response",
            latex=r"\omega_n^{-1}",
        ),
        Parameter(
            "zeta_reg", "1", 0.7, LogNormal(0.7, 0.7), bounds=(0.0, math.inf),
            description="damping ratio of the regulator (< 1 rings); not tested when the "
            "regulator is instantaneous",
            latex=r"\zeta_\mathrm{reg}",
        ),
    )
    description = (
        "A proportional regulator with its valve spool and the tubing's air column "
        "responds like a mass-spring-damper: tau_n^2 p'' + 2 zeta_reg tau_n p' + p = "
        "p_cmd, with natural frequency 1/tau_n and damping ratio zeta_reg. Below the "
        "natural frequency it lags the command by 2 zeta_reg tau_n, like regulator_lag; "
        "a lightly damped regulator (zeta_reg < 1) overshoots and rings at each kink of "
        "the command and amplifies it near 1/tau_n. In the residual: the lag's signature "
        "(error growing with frequency, correlated with the command's rate), plus an "
        "amplitude error that changes sign with frequency instead of growing "
        "monotonically, and oscillations at the ringing frequency after sharp changes. "
        "Well damped with a small tau_n, it cannot be told apart from regulator_lag."
    )
    physics = staticmethod(_regulator_second_order)

    @classmethod
    def history_s(cls, q: np.ndarray) -> np.ndarray:
        """40 slowest decay times: ``tau_n / zeta`` ringing, ``tau_n (zeta + sqrt(zeta^2 - 1))``
        over-damped (see :meth:`Effect.history_s`)."""
        tau, zeta = q[:, 0], q[:, 1]
        slow = np.where(zeta < 1.0, tau / zeta,
                        tau * (zeta + np.sqrt(np.maximum(zeta * zeta - 1.0, 0.0))))
        return 40.0 * slow

    @classmethod
    def lead_s(cls, q: np.ndarray) -> np.ndarray:
        """``2 zeta tau_n``, its low-frequency lag (see :meth:`Effect.lead_s`)."""
        return 2.0 * q[:, 1] * q[:, 0]


def delay_effect() -> type[Effect]:
    """The effect a model gains to lengthen its delay when none of its effects can.

    The gain rule's delay margin (:func:`pmabayes.control.tune_gains`) adds it at its
    null values, then lengthens its delay with :meth:`Effect.add_delay`.

    Returns
    -------
    type
        :class:`TransportDelay`.
    """
    return TransportDelay
