"""The Bouc-Wen law, written once: its parameters' columns, the law, its linearisation,
its solutions, and the source text the simulator's generated kernels use for it.

The base model's hysteretic force ``z`` (N) follows, per unit of displacement,

::

    dz/dx = alpha - c g(|z|) |z|,   c = beta sgn(dx z) + gamma,

with ``g = 1`` unless a hysteresis effect gives it (:class:`~pmabayes.model.effects.Effect`
of stage ``"hysteresis"``). Every other module (the simulator's code generation, the
linearisation, the control's operating point, the paper's area) asks this module
rather than writing the law again. The sign convention: ``sgn(0) = +1``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np


class NamedParameters(Protocol):
    """What :meth:`BoucWenColumns.of` reads of a model: its parameters' names in column
    order (a :class:`~pmabayes.model.model.Model` has them; model.py imports this module,
    so it is not imported here)."""

    @property
    def parameter_names(self) -> Sequence[str]: ...


__all__ = ["BOUC_WEN_PARAMETERS", "BoucWenColumns", "direction_sign", "coefficient", "slope",
           "linearised", "along", "loading_branch", "coefficient_code", "slope_code",
           "rate_code", "update_code"]

#: The law's own parameters, in the order the base model lists them.
BOUC_WEN_PARAMETERS: tuple[str, ...] = ("alpha", "beta", "gamma")


@dataclass(frozen=True)
class BoucWenColumns:
    """Columns of a model's parameter array that hold the base model: the Bouc-Wen
    law's ``alpha``, ``beta`` and ``gamma``, the linear plant's ``d`` and ``K_e``,
    and the dead zone ``p_dz`` (None on a force-driven rig, which has none).

    Parameters
    ----------
    alpha, beta, gamma, d, k_e : int
        Columns of ``alpha`` (N/m), ``beta``, ``gamma`` (1/m), ``d`` (N s/m) and
        ``K_e`` (N/m).
    p_dz : int or None
        Column of ``p_dz`` (Pa).
    """

    alpha: int
    beta: int
    gamma: int
    d: int
    k_e: int
    p_dz: int | None

    @classmethod
    def of(cls, model: NamedParameters) -> BoucWenColumns:
        """The columns in ``model``'s parameter order.

        Parameters
        ----------
        model : Model
            The composed model (anything with ``parameter_names``).

        Returns
        -------
        BoucWenColumns
        """
        names = tuple(model.parameter_names)
        return cls(*(names.index(n) for n in (*BOUC_WEN_PARAMETERS, "d", "K_e")),
                   names.index("p_dz") if "p_dz" in names else None)

    def law(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(alpha, beta, gamma)`` of a parameter array (``(..., n_parameters)``).

        Parameters
        ----------
        theta : numpy.ndarray
            Parameter array, one set per row (or one set).

        Returns
        -------
        tuple of numpy.ndarray
            Each of shape ``theta.shape[:-1]``.
        """
        return theta[..., self.alpha], theta[..., self.beta], theta[..., self.gamma]


def direction_sign(dx, z):
    """``sgn(dx z)`` with ``sgn(0) = +1``: +1 while ``|z|`` grows (loading), else -1.

    Parameters
    ----------
    dx : float or numpy.ndarray
        Displacement (or velocity): the direction of motion.
    z : float or numpy.ndarray
        The hysteretic force.

    Returns
    -------
    float or numpy.ndarray
    """
    return (dx * z >= 0.0) * 2.0 - 1.0


def coefficient(dx, z, beta, gamma):
    """The law's ``c = beta sgn(dx z) + gamma`` (1/m).

    Parameters
    ----------
    dx, z : float or numpy.ndarray
        Direction of motion and hysteretic force (:func:`direction_sign`).
    beta, gamma : float or numpy.ndarray
        The law's parameters.

    Returns
    -------
    float or numpy.ndarray
    """
    return beta * direction_sign(dx, z) + gamma


def slope(dx, z, alpha, beta, gamma, g=None):
    """``dz/dx = alpha - c g |z|``, the law's rate per unit of displacement (N/m).

    Parameters
    ----------
    dx, z : float or numpy.ndarray
        Direction of motion and hysteretic force.
    alpha, beta, gamma : float or numpy.ndarray
        The law's parameters.
    g : float or numpy.ndarray, optional
        A hysteresis effect's factor at ``|z|``; none (1) by default.

    Returns
    -------
    float or numpy.ndarray
    """
    c = coefficient(dx, z, beta, gamma)
    return alpha - (c if g is None else c * g) * abs(z)


def linearised(v, z, alpha, beta, gamma, g=1.0, dg=0.0):
    """The law in time, ``z' = (alpha - c g(|z|) |z|) v``, to first order:
    ``dz' = kz dv + bz dz`` (the branch, ``sgn(v z)``, held).

    Parameters
    ----------
    v, z : float or numpy.ndarray
        Velocity and hysteretic force.
    alpha, beta, gamma : float or numpy.ndarray
        The law's parameters.
    g, dg : float or numpy.ndarray
        A hysteresis effect's factor ``g`` at ``|z|`` and its derivative in ``|z|``
        (1 and 0 without one).

    Returns
    -------
    tuple
        ``(kz, bz)``: ``kz = dz/dx`` (N/m) and ``bz`` (1/s).
    """
    c = coefficient(v, z, beta, gamma)
    az = abs(z)
    kz = alpha - c * g * az
    bz = -v * c * np.where(z >= 0.0, 1.0, -1.0) * (g + az * dg)
    return kz, bz


def along(dx: np.ndarray, alpha: float, beta: float, gamma: float, z0: float = 0.0
          ) -> np.ndarray:
    """``z`` along a path of displacement increments, from ``z0``, by the midpoint rule
    (an Euler predictor, then the midpoint corrector; ``g = 1``).

    Parameters
    ----------
    dx : numpy.ndarray
        The path's increments in m, ``(n,)``.
    alpha, beta, gamma : float
        The law's parameters.
    z0 : float
        ``z`` at the path's start.

    Returns
    -------
    numpy.ndarray
        ``z`` at the ``n + 1`` points of the path.
    """
    z = np.zeros(len(dx) + 1)
    z[0] = z0
    for k, step in enumerate(dx):
        for corrector in (False, True):
            zm = 0.5 * (z[k] + z[k + 1]) if corrector else z[k]
            z[k + 1] = z[k] + step * slope(step, zm, alpha, beta, gamma)
    return z


def loading_branch(dx: float, alpha: float, beta: float, gamma: float) -> float:
    """``z`` after a monotonic extension ``dx >= 0`` from ``z = 0``: the loading branch
    ``dz/dx = alpha - (beta + gamma) z``, solved exactly (``g = 1``).

    ``z(dx) = alpha / c (1 - exp(-c dx))`` with ``c = beta + gamma`` (``alpha dx`` for
    ``c = 0``).

    Parameters
    ----------
    dx : float
        The extension in m.
    alpha, beta, gamma : float
        The law's parameters.

    Returns
    -------
    float
        ``z`` in N.
    """
    c = beta + gamma
    return alpha * dx if c == 0 else alpha / c * -math.expm1(-c * dx)


# ---------------------------------------------------------------------------------
# Source text for generated kernels. ``alpha``, ``beta`` and ``gamma`` are the
# expressions of the law's constants in the generated code (e.g. ``cst[8, i]``); the
# emitted lines set the names ``c`` and ``kz`` (and work names of their own).


def coefficient_code(z: str, dx: str, beta: str, gamma: str) -> str:
    """The line setting ``c`` (:func:`coefficient`) for motion in the direction of ``dx``.

    Parameters
    ----------
    z, dx : str
        Expressions of the hysteretic force and of the direction of motion.
    beta, gamma : str
        Expressions of the law's constants.

    Returns
    -------
    str
    """
    return f"c = {beta} * (1.0 if {dx} * {z} >= 0.0 else -1.0) + {gamma}"


def slope_code(z: str, alpha: str, g: str | None = None) -> str:
    """The expression of ``dz/dx = alpha - c g |z|`` (:func:`slope`), ``c`` already set.

    Parameters
    ----------
    z : str
        Expression of the hysteretic force.
    alpha : str
        Expression of ``alpha`` (times a law's factor of it, if any).
    g : str, optional
        Expression of a hysteresis effect's factor; none by default (or already in ``c``).

    Returns
    -------
    str
    """
    return f"{alpha} - c * {g} * abs({z})" if g else f"{alpha} - c * abs({z})"


def rate_code(z: str, dx: str, alpha: str, beta: str, gamma: str) -> list[str]:
    """Lines setting ``c`` and ``kz = dz/dx`` at ``z`` for motion in the direction of ``dx``.

    Parameters
    ----------
    z, dx : str
        Expressions of the hysteretic force and of the direction of motion.
    alpha, beta, gamma : str
        Expressions of the law's constants.

    Returns
    -------
    list of str
    """
    return [coefficient_code(z, dx, beta, gamma), f"kz = {slope_code(z, alpha)}"]


def _phi_code(y: str, out: str) -> list[str]:
    """Lines setting ``out = phi(y) = (e^y - 1) / y`` without division or branch.

    With ``q = y / 8`` and ``E = e^q``: ``phi(y) = phi(q) (E + 1)(E^2 + 1)(E^4 + 1) / 8``,
    and ``phi(q)`` is a Taylor polynomial (relative error < 1e-14 for ``|y| <= 2``).
    """
    return [
        f"q = 0.125 * ({y})",
        "phq = 1.0 + q * (1 / 2 + q * (1 / 6 + q * (1 / 24 + q * (1 / 120 + q * (1 / 720 + q * ("
        "1 / 5040 + q * (1 / 40320 + q / 362880)))))))",
        "eq = 1.0 + q * phq",
        "eq2 = eq * eq",
        f"{out} = 0.125 * phq * (eq + 1.0) * (eq2 + 1.0) * (eq2 * eq2 + 1.0)",
    ]


def update_code(z: str, dx: str, out: str, alpha: str, beta: str, gamma: str,
                scale: str | None = None, alpha_scale: str | None = None) -> list[str]:
    """Lines setting ``out`` to the exact Bouc-Wen ``z`` after displacement ``dx``.

    Emitted inline (a call would stop the batch loop from vectorising); uses ``c``
    and ``kz`` from :func:`rate_code`. On one branch (fixed signs of ``dx``
    and ``z``) ``dz/dx = alpha - c sgn(z) z`` is linear, so
    ``z(dx) = z + dx kz phi(-c sgn(z) dx)``. A step that carries ``z`` through zero
    changes branch there: it is split at the zero (distance ``d0``, exact on the
    approach branch) and finished on the departing branch, where ``sgn(dx z) = +1``.
    Getting this wrong is not a local error: the hysteresis remembers it. Both are
    computed and one selected, to stay branch-free.

    Parameters
    ----------
    z, dx : str
        Expressions of ``z`` at the step's start and of the displacement.
    out : str
        Name set to the new ``z``.
    alpha, beta, gamma : str
        Expressions of the law's constants.
    scale : str, optional
        A hysteresis effect's factor ``g``, frozen over the step: the departing
        branch's ``c`` is scaled by it too (``c`` and ``kz`` must already be).
    alpha_scale : str, optional
        A stateful law's factor of ``alpha``, for the departing branch's ``alpha``.

    Returns
    -------
    list of str
    """
    lines = [f"sz = 1.0 if {z} >= 0.0 else -1.0"]
    lines += _phi_code(f"-c * sz * {dx}", "ph")
    lines += [f"z_nc = {z} + {dx} * kz * ph"]
    # crossing: z and dx of opposite sign, and dx reaches past the zero of z; the
    # zero is at d0 = d_lin / phi(y0), with 1 / phi(y) = y / (e^y - 1) as its
    # Bernoulli series (no division; converges for |y| < 2 pi)
    lines += [
        f"d0 = -{z} / (kz if kz > 1e-300 else 1e-300)",
        "y0 = -c * sz * d0",
        "y02 = y0 * y0",
        "d0 *= 1.0 - 0.5 * y0 + y02 * (1 / 12 + y02 * (-1 / 720 + y02 * ("
        "1 / 30240 - y02 / 1209600)))",
        f"rem = {dx} - d0",
        f"cross = ({z} * {dx} < 0.0) & (kz > 0.0) & (abs({dx}) > abs(d0))",
        f"c2 = {beta} + {gamma}" + (f"; c2 *= {scale}" if scale else ""),
    ]
    lines += _phi_code("-c2 * abs(rem)", "ph2")
    departing_alpha = alpha + (f" * {alpha_scale}" if alpha_scale else "")
    lines += [f"{out} = rem * {departing_alpha} * ph2 if cross else z_nc"]
    return lines
