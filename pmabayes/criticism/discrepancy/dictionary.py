"""The dictionary of named physical terms a closed form is made of, each with its unit,
its words and its expression for a user effect; and the period, breakpoints and
tabulated shape fitted to the residual.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, PPoly

from pmabayes.criticism.discrepancy.linalg import a_b, at_b, orthonormal, spd_solve
from pmabayes.criticism.discrepancy.problem import Block, LinearProblem

__all__ = ["Term"]


@dataclass(frozen=True)
class Term:
    """One named physical term of the closed-form dictionary.

    Parameters
    ----------
    name : str
        The term as written, e.g. ``"v|v|"``.
    unit : str
        Unit of its coefficient (N per unit of the term).
    words : str
        What a force of this form is, physically.
    state : str
        The state it mainly depends on (one of
        :data:`~pmabayes.criticism.discrepancy.problem.STATES`).
    force : str or None
        Numba-compatible expression in ``x``, ``v``, ``p``, and ``z`` (the
        hysteretic force) or ``s`` (the memory state) where the term needs them;
        None if it cannot be written as an effect.
    dx, dv : str
        Its derivatives in ``x`` and ``v``.
    dz, ds : str
        Its derivatives in ``z`` and in the memory state.
    slug : str
        Identifier fragment for parameter names.
    period_m : float or None
        For a term periodic in position, its period: ``{L}`` in the expressions,
        written as a parameter of the effect that the refit adjusts.
    breakpoint_m : float or None
        For a spring acting below a position, that position: ``{B}`` in the
        expressions, a parameter of the effect like the period.
    memory_tau_s : float or None
        For the memory term, the time constant of its low-passed velocity ``s``.
    loop_width_m : float or None
        For the loop term, the travel over which its state ``s`` saturates.
    """

    name: str
    unit: str
    words: str
    state: str
    force: str | None
    dx: str = "0.0"
    dv: str = "0.0"
    slug: str = ""
    period_m: float | None = None
    breakpoint_m: float | None = None
    dz: str = "0.0"
    ds: str = "0.0"
    memory_tau_s: float | None = None
    loop_width_m: float | None = None

    @property
    def writable(self) -> bool:
        """Whether a force-stage effect can express it."""
        return self.force is not None

    @property
    def reads_z(self) -> bool:
        """Whether its effect needs the hysteretic force ``z``."""
        return self.state == "hysteresis"


def _f(value: float) -> str:
    return repr(float(f"{value:.6g}"))


def dictionary_terms(st: dict, memory_tau_s: float, period_m: float | None, hinges: tuple,
                     loop_width_m: float) -> list:
    """The named terms and their values along the trajectory."""
    x, v, p, z = st["position"], st["velocity"], st["pressure"], st["hysteresis"]
    mm = 1e3
    terms = [
        (Term("1", "N", "a constant force", "position", "1.0", slug="const"), np.ones_like(x)),
        (Term("x^2", "N/m^2", "a quadratic spring", "position", "x * x", "2.0 * x", slug="x2"),
         x**2),
        (Term("x^3", "N/m^3", "a cubic (hardening) spring", "position", "x * x * x",
              "3.0 * x * x", slug="x3"), x**3),
        (Term("v|v|", "N s^2/m^2", "a quadratic drag", "velocity",
              "v * abs(v)", dv="2.0 * abs(v)", slug="vabsv"), v * np.abs(v)),
        (Term("v^3", "N s^3/m^3", "a cubic damping", "velocity", "v * v * v",
              dv="3.0 * v * v", slug="v3"), v**3),
        (Term("|v|", "N s/m", "a force growing with speed in either direction", "velocity",
              "abs(v)", dv="(1.0 if v >= 0.0 else -1.0)", slug="absv"), np.abs(v)),
        (Term("p x", "N/(m Pa)", "a stiffness growing with pressure", "pressure", "p * x",
              "p", slug="px"), p * x),
        (Term("p v", "N s/(m Pa)", "a damping growing with pressure", "pressure", "p * v",
              dv="p", slug="pv"), p * v),
        (Term("p", "N/Pa", "a force proportional to pressure (an area error)", "pressure",
              "p", slug="p"), p),
        (Term("x [v>0]", "N/m", "a stiffness acting only while extending", "direction",
              "(x if v > 0.0 else 0.0)", "(1.0 if v > 0.0 else 0.0)", slug="xext"),
         np.where(v > 0, x, 0.0)),
        (Term("z|z|", "1/N", "a hysteretic force growing as z|z| (a Bouc-Wen exponent above "
              "1)", "hysteresis", "z * abs(z)", dz="2.0 * abs(z)", slug="zabsz"),
         z * np.abs(z)),
        (Term(f"v_lp(tau={memory_tau_s:g} s)", "N s/m",
              f"a force remembering the velocity over {memory_tau_s:g} s (creep, "
              "viscoelastic memory)", "memory", "s", ds="1.0", slug="vlp",
              memory_tau_s=float(memory_tau_s)), st["memory"]),
        (Term(f"h_loop(width={loop_width_m * mm:.3g} mm)", "N",
              f"a friction loop saturating over {loop_width_m * mm:.3g} mm of travel after "
              "each reversal (Dahl friction: a second hysteresis)", "loop", "s", ds="1.0",
              slug="hloop", loop_width_m=float(loop_width_m)), st["loop"]),
    ]
    z_big = float(np.max(np.abs(z))) if z.size else 0.0
    if z.min() < -0.1 * z_big and z.max() > 0.1 * z_big:
        # where z keeps one sign, |z| is +-z, and a force c z is the base model itself
        # with alpha, beta and gamma rescaled (z' = (1 + c) z obeys Bouc-Wen's law with
        # (1 + c) alpha, beta / (1 + c), gamma / (1 + c)): not identifiable, so not offered
        terms.append((Term("|z|", "1", "a force in |z| (hysteresis acting one way)",
                           "hysteresis", "abs(z)", dz="(1.0 if z >= 0.0 else -1.0)",
                           slug="absz"), np.abs(z)))
    for v0 in (5e-4, 5e-3, 5e-2):
        s = _f(v0)
        terms.append((Term(f"tanh(v/{v0 * mm:g} mm/s)", "N",
                           f"a friction force, smoothed over {v0 * mm:g} mm/s",
                           "velocity", f"math.tanh(v / {s})",
                           dv=f"(1.0 - math.tanh(v / {s}) ** 2) / {s}",
                           slug=f"tanh{v0 * mm:g}".replace(".", "p")), np.tanh(v / v0)))
    below, above = hinges
    for k, b in enumerate(below):
        terms.append((Term(f"(x - {b * mm:.3g} mm) [x<{b * mm:.3g} mm]", "N/m",
                           f"a spring acting only below x = {b * mm:.3g} mm (in compression)",
                           "position", "((x - {B}) if x < {B} else 0.0)",
                           "(1.0 if x < {B} else 0.0)", slug=f"xlo{k}", breakpoint_m=b),
                      np.where(x < b, x - b, 0.0)))
    for k, b in enumerate(above):
        s = _f(b)
        terms.append((Term(f"(x - {b * mm:.3g} mm) [x>{b * mm:.3g} mm]", "N/m",
                           f"a spring engaging only above x = {b * mm:.3g} mm (an end stop)",
                           "position", f"((x - {s}) if x > {s} else 0.0)",
                           f"(1.0 if x > {s} else 0.0)", slug=f"xhi{k}"),
                      np.where(x > b, x - b, 0.0)))
    if period_m is not None:
        k = "6.283185307179586"
        words = (f"a force periodic in position with a period of {period_m * mm:.3g} mm "
                 "(detents of a rail, a ratchet)")
        terms.append((Term(f"sin(2 pi x / {period_m * mm:.3g} mm)", "N", words, "position",
                           f"math.sin({k} * x / {{L}})",
                           f"{k} / {{L}} * math.cos({k} * x / {{L}})", slug="sin",
                           period_m=period_m), np.sin(2 * math.pi * x / period_m)))
        terms.append((Term(f"cos(2 pi x / {period_m * mm:.3g} mm)", "N", words, "position",
                           f"math.cos({k} * x / {{L}})",
                           f"-{k} / {{L}} * math.sin({k} * x / {{L}})", slug="cos",
                           period_m=period_m), np.cos(2 * math.pi * x / period_m)))
    return terms


def _best_of(problem: LinearProblem, families: list) -> int:
    """Index of the family of force columns (each ``(n, k)``) that removes most residual."""
    forces = np.concatenate(families, axis=1)
    _, gw = problem.responses(forces)
    q = orthonormal(problem.j_w)
    r0 = problem.r_w - a_b(q, at_b(q, problem.r_w))
    gains, k = [], 0
    for fam in families:
        g = gw[:, k:k + fam.shape[1]]
        k += fam.shape[1]
        g = g - a_b(q, at_b(q, g))
        coef = spd_solve(at_b(g, g) + 1e-12 * np.eye(g.shape[1]), at_b(g, r0))
        gains.append(float(r0 @ r0 - np.sum((r0 - a_b(g, coef)) ** 2)))
    return int(np.argmax(gains))


def best_period(problem: LinearProblem, x: np.ndarray) -> float | None:
    """The period of a force periodic in position that best explains the residual."""
    span = float(np.ptp(x))
    if not span > 0:
        return None
    def fams(periods):
        return [np.stack([np.sin(2 * np.pi * x / L), np.cos(2 * np.pi * x / L)], axis=1)
                for L in periods]

    coarse = np.geomspace(span / 60.0, span / 2.0, 48)
    best = coarse[_best_of(problem, fams(coarse))]
    # then finely: over the span a period off by 1% drifts by a tenth of a period
    fine = best * np.geomspace(0.93, 1.075, 41)
    return float(fine[_best_of(problem, fams(fine))])


def best_hinges(problem: LinearProblem, x: np.ndarray) -> tuple:
    """Where a spring acting only below (and one acting only above) a position best fits."""
    below = np.quantile(x, np.linspace(0.02, 0.6, 30))
    above = np.quantile(x, np.linspace(0.4, 0.98, 30))
    b = below[_best_of(problem, [np.where(x < c, x - c, 0.0)[:, None] for c in below])]
    a = above[_best_of(problem, [np.where(x > c, x - c, 0.0)[:, None] for c in above])]
    return (float(b),), (float(a),)


def tabulated_term(b: Block, w: np.ndarray):
    """The flexible shape in one state as a piecewise cubic with fixed coefficients."""
    spline = BSpline(b.knots, w, 3, extrapolate=False)
    pp = PPoly.from_spline(spline)
    keep = np.flatnonzero(np.diff(pp.x) > 0)
    brk = np.concatenate([pp.x[keep], [pp.x[keep[-1] + 1]]])
    coefs = pp.c[:, keep]
    sym = {"position": "x", "velocity": "v", "pressure": "p"}[b.state]
    series = a_b(b.basis, w)
    mean = float(np.mean(series))
    coefs = coefs.copy()
    coefs[-1] -= mean  # centred: a constant would shift the rest position only
    values = series - mean
    t = Term(f"S_{sym}({sym})", "1", f"the estimated force shape in {b.state}, tabulated",
             b.state, "shape", "0.0", "0.0", slug=f"shape_{sym}")
    if sym == "x":
        t = Term(t.name, t.unit, t.words, t.state, t.force, "slope", "0.0", t.slug)
    elif sym == "v":
        t = Term(t.name, t.unit, t.words, t.state, t.force, "0.0", "slope", t.slug)
    return (t, values), (brk, coefs)
