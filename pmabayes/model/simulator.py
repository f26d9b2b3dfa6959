"""Batched, compiled simulation of a composed :class:`~pmabayes.model.model.Model`.

Each sample interval is integrated by a second-order scheme that is stable at any
step: the linear mass-spring-damper discretised exactly for a force linear over the
interval, the remaining force found by one linearly implicit step, and the Bouc-Wen
force ``z`` advanced by the exact solution of its law over the step's displacement.
Kernels are generated per composition of effects, compiled with numba and cached on
disk (``$PMABAYES_CACHE_DIR``, default ``~/.cache/pmabayes``). A record starts at
rest, at zero, from a given (estimated) state, or in a periodic steady state found by
Newton's method on the period map. The documentation's page "The
simulator" (``docs/theory/simulator.rst``) gives the scheme and the input conventions.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import os
import sys
import tempfile
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from pmabayes.data import BETWEEN_SAMPLES, INITIAL_STATES, check_time_grid
from pmabayes.model.model import Model
from pmabayes.util import Progress, fingerprint, source_text

__all__ = ["simulate", "simulate_dataset", "Simulation", "kernel_for", "cache_dir",
           "SimulationError", "SteadyStateWarning", "OverflowingStepWarning",
           "collect_steady_state_misses", "BETWEEN_SAMPLES", "INITIAL_STATES",
           "STEADY_STATE_TOL_M", "MAX_WARMUP_PERIODS", "POSITION_REFERENCES",
           "warmup_settings", "position_reference"]

#: numba fastmath flags of every generated kernel. ``contract`` (fused multiply-add)
#: and ``afn`` (approximate functions) let results differ in the last bits between
#: CPUs and numba/LLVM versions, never between runs on one machine and install.
FASTMATH = {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}


class SimulationError(ValueError):
    """Inputs to the simulator are inconsistent."""


@numba.njit(cache=True)
def _discretise(mass, damping, stiffness, dt, out):
    """Exact first-order-hold discretisation of m x'' + d x' + K x = u.

    Writes [P00, P01, P10, P11, G0, G1, H0, H1] to ``out``: for u rising linearly
    from u0 to u0 + du over dt, (x, v) <- P (x, v) + G u0 + H du.
    """
    m = np.zeros((4, 4))
    m[0, 1] = dt
    m[1, 0] = -stiffness / mass * dt
    m[1, 1] = -damping / mass * dt
    m[1, 2] = dt / mass
    m[2, 3] = 1.0
    norm = 0.0
    for r in range(4):
        s = 0.0
        for c in range(4):
            s += abs(m[r, c])
        norm = max(norm, s)
    squarings = 0
    # a finite norm (below 2^1024) needs at most 1026 halvings; an infinite one (a
    # stiffness or damping over the mass that overflows) would halve for ever. The
    # bound is a count, which the kernels' fastmath (no infinities) cannot fold away
    while norm > 0.25 and squarings < 1100:
        norm *= 0.5
        squarings += 1
    if squarings == 1100:  # no finite step: NaN, a likelihood's -inf (_say_overflow says)
        for r in range(8):
            out[r] = np.nan
        return
    scale = 0.5**squarings
    for r in range(4):
        for c in range(4):
            m[r, c] *= scale
    e = np.eye(4)
    term = np.eye(4)
    for n in range(1, 19):  # Taylor series, converged to rounding for ||m|| <= 1/4
        term = term @ m / n
        e += term
    for _ in range(squarings):
        e = e @ e
    out[0] = e[0, 0]
    out[1] = e[0, 1]
    out[2] = e[1, 0]
    out[3] = e[1, 1]
    out[4] = e[0, 2]
    out[5] = e[1, 2]
    out[6] = e[0, 3]
    out[7] = e[1, 3]


def bw_rate_lines(z: str, dx: str, cst: str = "cst") -> list[str]:
    """Code setting ``c`` and ``kz = dz/dx`` at ``z`` for motion in the direction of ``dx``."""
    return [
        f"c = {cst}[9, i] * (1.0 if {dx} * {z} >= 0.0 else -1.0) + {cst}[10, i]",
        f"kz = {cst}[8, i] - c * abs({z})",
    ]


def _phi_lines(y: str, out: str) -> list[str]:
    """Code setting ``out = phi(y) = (e^y - 1) / y`` without division or branch.

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


def bw_update_lines(z: str, dx: str, out: str, cst: str = "cst",
                    scale: str | None = None, alpha_scale: str | None = None) -> list[str]:
    """Code setting ``out`` to the exact Bouc-Wen ``z`` after displacement ``dx``.

    Emitted inline (a call would stop the batch loop from vectorising); uses ``c``
    and ``kz`` from :func:`bw_rate_lines`. On one branch (fixed signs of ``dx``
    and ``z``) ``dz/dx = alpha - c sgn(z) z`` is linear, so
    ``z(dx) = z + dx kz phi(-c sgn(z) dx)``. A step that carries ``z`` through zero
    changes branch there: it is split at the zero (distance ``d0``, exact on the
    approach branch) and finished on the departing branch, where ``sgn(dx z) = +1``.
    Getting this wrong is not a local error: the hysteresis remembers it. Both are
    computed and one selected, to stay branch-free. With ``scale`` (a hysteresis
    effect's factor ``g``, frozen over the step) the departing branch's ``c`` is
    scaled too (``c`` and ``kz`` must already be), and with ``alpha_scale`` (a
    stateful law's factor of ``alpha``) its ``alpha``.
    """
    lines = [f"sz = 1.0 if {z} >= 0.0 else -1.0"]
    lines += _phi_lines(f"-c * sz * {dx}", "ph")
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
        f"c2 = {cst}[9, i] + {cst}[10, i]" + (f"; c2 *= {scale}" if scale else ""),
    ]
    lines += _phi_lines("-c2 * abs(rem)", "ph2")
    alpha = f"{cst}[8, i]" + (f" * {alpha_scale}" if alpha_scale else "")
    lines += [f"{out} = rem * {alpha} * ph2 if cross else z_nc"]
    return lines


# ---------------------------------------------------------------------------------
# Code generation
#
# Internal code-generation API. ``FASTMATH``, ``bw_rate_lines``, ``bw_update_lines``,
# ``indent_lines``, ``PlantCode``, ``structure_key``, ``cached_kernel`` and
# ``compile_kernel`` are shared with :mod:`pmabayes.control`, whose closed-loop kernel
# is generated from the same plant lines, and so is ``discretise``, the compiled
# helper the generated step code calls (as ``_discretise``). They are not part of the
# public API (not in ``__all__``) and may change with the kernels.

#: The discretisation the generated plant step calls, for kernels generated elsewhere.
discretise = _discretise

_HEADER = '''\
# Generated by pmabayes.model.simulator for effects: {effects}. Do not edit.
import math
import numpy as np
from numba import njit
from pmabayes.model.simulator import _discretise
'''


def indent_lines(lines: list[str], n: int) -> str:
    """Join generated ``lines`` indented by ``n`` spaces (blank lines stay empty)."""
    return "\n".join(" " * n + ln if ln else "" for ln in lines)


def _inlined(dispatcher):
    fn = getattr(dispatcher, "py_func", dispatcher)
    return numba.njit(inline="always", error_model="numpy")(fn)


def state_rows(model: Model) -> int:
    """Rows of a kernel's state: ``x``, ``v``, ``z``, one per force effect with a state,
    and the hysteresis effect's last factor ``g`` (with a state: its last factor of
    ``alpha`` and its state too) (:class:`PlantCode`)."""
    law = [e for e in model.effects if e.stage == "hysteresis"]
    return (3 + sum(1 for e in model.effects if e.stage == "force" and e.state is not None)
            + (1 if law else 0) + (2 if law and law[0].state is not None else 0))


class PlantCode:
    """Generated source lines of one model's physics, for kernels built from them (internal).

    The open-loop kernel below and the closed loop in :mod:`pmabayes.control` are
    generated from these same lines, so the two integrate the plant identically.
    Names in the emitted code: ``theta`` (the ``(batch, n_parameters)`` array) and
    ``cst`` (per-member constants, rows: 8 discretisation coefficients, alpha,
    beta, gamma, p_dz) can be renamed so that two models share one kernel; ``i`` is
    the batch member; ``mass``, ``f_grav``, ``area``, ``dt`` and ``substeps`` are
    kernel arguments. The state lives in rows of ``st``: ``x``, ``v``, ``z``, then
    one row per force effect with a state, then, with a hysteresis effect, its
    factor ``g`` over the last step, and for a law with a state its factor of
    ``alpha`` over the last step and the state (:attr:`n_rows` in all); :meth:`step`
    reads and writes these rows itself.
    """

    def __init__(self, model: Model, *, theta: str = "theta", cst: str = "cst",
                 prefix: str = "_eff") -> None:
        self.model = model
        self.theta = theta
        self.cst = cst
        slices = model.effect_slices()
        self.pressure = [(e, s) for e, s in slices if e.stage == "pressure"]
        self.force = [(e, s) for e, s in slices if e.stage == "force"]
        self.measure = [(e, s) for e, s in slices if e.stage == "measurement"]
        self.law = [(e, s) for e, s in slices if e.stage == "hysteresis"]  # at most one
        self.dead_zone = model.rig.input_kind == "pressure"
        # force and hysteresis physics is inlined at numba's IR level so the batch loop
        # can vectorise
        self.inject = {
            f"{prefix}{j}": (_inlined(e.physics) if e.stage in ("force", "hysteresis")
                             else e.physics)
            for j, (e, _) in enumerate(slices)
        }
        self.name_of = {e: f"{prefix}{j}" for j, (e, _) in enumerate(slices)}
        stateful = [e for e, _ in self.force if e.state is not None]
        self.inject.update({f"{self.name_of[e]}_adv": _inlined(e.advance)
                            for e in stateful + [e for e, _ in self.law if e.state]})
        #: row of ``st`` holding each stateful force effect's state
        self.state_row = {e: 3 + j for j, e in enumerate(stateful)}
        self.reads_z = any(e.reads_z for e, _ in self.force)
        #: row of ``st`` holding the hysteresis effect's last factor ``g``
        self.law_row = 3 + len(self.state_row) if self.law else None
        #: a hysteresis law with a state: rows of its last factor of alpha and its state
        self.law_state = bool(self.law) and self.law[0][0].state is not None
        #: columns of the rig values identified as parameters: they enter per member,
        #: through rows 12 (area) and 13 (gravity force) of ``cst``
        self.rig_cols = model.rig_columns

    @property
    def n_rows(self) -> int:
        """Rows of the state array ``st``: ``x``, ``v``, ``z``, the effects' states, ``g``."""
        return state_rows(self.model)

    def q(self, e) -> str:
        """Name of the contiguous parameter rows of force effect ``e``."""
        return f"q{self.name_of[e]}"

    def setup(self) -> list[str]:
        """Lines filling ``cst`` and the force effects' parameter rows."""
        t, c = self.theta, self.cst
        rig = self.rig_cols
        mass = f"{t}[i, {rig['moving_mass_kg']}]" if "moving_mass_kg" in rig else "mass"
        lines = [
            f"{c} = np.empty(({14 if rig else 12}, {t}.shape[0]))",
            "col = np.empty(8)",
            f"for i in range({t}.shape[0]):",
            # alpha (the hysteresis' initial stiffness) joins the exact linear part; only
            # the remainder r = z - alpha x is taken as linear in time over a step
            f"    _discretise({mass}, {t}[i, 3], {t}[i, 4] + {t}[i, 0], dt / substeps, col)",
            f"    {c}[:8, i] = col",
            f"    {c}[8, i] = {t}[i, 0]",
            f"    {c}[9, i] = {t}[i, 1]",
            f"    {c}[10, i] = {t}[i, 2]",
            f"    {c}[11, i] = {t + '[i, 5]' if self.dead_zone else '0.0'}",
        ]
        if rig:  # the kernel's mass, f_grav and area are the rig's nominal values
            area = f"{t}[i, {rig['area_m2']}]" if "area_m2" in rig else "area"
            lines += [f"    {c}[12, i] = {area}", f"    {c}[13, i] = f_grav * ({mass} / mass)"]
        # contiguous per-effect parameter rows: a strided slice defeats vectorisation
        lines += [f"{self.q(e)} = {t}[:, {s.start}:{s.stop}].copy()"
                  for e, s in self.force + self.law]
        return lines

    def actuator(self, p: str) -> str:
        """Expression of the actuator force minus gravity at pressure ``p``."""
        area, f_grav = ((f"{self.cst}[12, i]", f"{self.cst}[13, i]") if self.rig_cols
                        else ("area", "f_grav"))
        if self.dead_zone:
            return f"{area} * max({p} - {self.cst}[11, i], 0.0) - {f_grav}"
        return f"{area} * {p} - {f_grav}"

    def balance(self, p: str, x: str, v: str, out: str) -> list[str]:
        """Lines setting ``out`` to the hysteretic force ``z`` that balances the actuator,
        the spring, the damper and the force effects (at ``z = 0``) at position ``x``,
        velocity ``v`` and pressure ``p``: the ``z`` of zero acceleration."""
        t = self.theta
        return [*self.forces(x, v, p, "fb", False),
                f"{out} = {self.actuator(p)} - {t}[i, 4] * {x} - {t}[i, 3] * {v} - fb"]

    def forces(self, x: str, v: str, p: str, out: str, derivs: bool, z: str = "0.0",
               states: dict | None = None, slopes: dict | None = None) -> list[str]:
        """Lines summing the force effects into ``out`` (and ``out_x``, ``out_v``).

        Effects that read ``z`` or carry a state get ``z`` and ``states[effect]`` (0
        by default: the rest state). With ``derivs`` and ``reads_z``, ``out_z`` sums
        the derivatives in ``z``; a state's derivative enters ``out_x`` through
        ``slopes[effect]``, the state's derivative in the end position.
        """
        lines = [f"{out} = 0.0"] + ([f"{out}_x = 0.0", f"{out}_v = 0.0"] if derivs else [])
        if derivs and self.reads_z:
            lines += [f"{out}_z = 0.0"]
        for e, _ in self.force:
            if not e.extended():
                lines.append(f"r = {self.name_of[e]}({self.q(e)}[i], {x}, {v}, {p})")
            else:
                state = (states or {}).get(e, "0.0")
                lines.append(f"r = {self.name_of[e]}({self.q(e)}[i], {x}, {v}, {p}, {z}, "
                             f"{state})")
            lines.append(f"{out} += r[0]")
            if derivs:
                lines += [f"{out}_x += r[1]", f"{out}_v += r[2]"]
                if e.reads_z:
                    lines += [f"{out}_z += r[3]"]
                if e in (slopes or {}):
                    lines += [f"{out}_x += r[4] * {slopes[e]}"]
        return lines

    def advance(self, e, state: str, x0: str, x1: str, h: str, out: str) -> list[str]:
        """Lines advancing stateful force effect ``e``'s state over a step into ``out``
        (and its derivative in ``x1`` into ``out_d``)."""
        return [f"r = {self.name_of[e]}_adv({self.q(e)}[i], {state}, {x0}, {x1}, {h})",
                f"{out} = r[0]", f"{out}_d = r[1]"]

    def rate_lines(self, z: str, dx: str, g_last: str = "0.0",
                   law_rows: tuple[str, str] | None = None) -> list[str]:
        """Lines setting ``c`` and ``kz = dz/dx`` at ``z`` for motion in the direction of ``dx``.

        With a hysteresis effect its factor ``g`` is evaluated once, at the step's mean
        ``|z|`` (the ends predicted with ``g_last``, the factor of the step before, an
        expression), and frozen over the step: ``c`` holds ``c g`` and ``gm`` holds
        ``g`` (store it for the next step's ``g_last``), for :meth:`update_lines`, whose
        Bouc-Wen step is then exact for that ``g``: second order in all. A law with a
        state needs ``law_rows``, the expressions of its last factor of ``alpha`` and of
        its state at the step's start: its two factors are evaluated at the step's
        predicted middle (signed ``z``, and the state advanced half a step) and frozen,
        ``ga`` the factor of ``alpha``.
        """
        if not self.law:
            return bw_rate_lines(z, dx, self.cst)
        e, c = self.law[0][0], self.cst
        sign = [f"c = {c}[9, i] * (1.0 if {dx} * {z} >= 0.0 else -1.0) + {c}[10, i]"]
        if e.state is None:
            return sign + [
                f"zm = 0.5 * (abs({z}) + abs({z} + ({c}[8, i] - c * {g_last} * abs({z})) * "
                f"{dx}))",
                f"gm = {self.name_of[e]}({self.q(e)}[i], zm)",
                "c *= gm",
                f"kz = {c}[8, i] - c * abs({z})",
            ]
        if law_rows is None:
            raise SimulationError(
                f"the hysteresis law {e.name!r} carries a state ({e.state!r}), which this "
                "kernel does not hold (the closed loop's observer cannot advance it yet); "
                "simulate it open loop, or use a law without a state")
        ga_last, state = law_rows
        return sign + [
            # (the factor of alpha before the first step is taken as 1)
            f"ga = {ga_last} if {ga_last} != 0.0 else 1.0",
            f"zm = {z} + 0.5 * ({c}[8, i] * ga - c * {g_last} * abs({z})) * {dx}",
            f"em = {self.name_of[e]}_adv({self.q(e)}[i], {state}, {z}, zm, 0.5 * {dx})",
            f"rg = {self.name_of[e]}({self.q(e)}[i], zm, {dx}, em)",
            "ga = rg[0]",
            "gm = rg[1]",
            "c *= gm",
            f"kz = {c}[8, i] * ga - c * abs({z})",
        ]

    def update_lines(self, z: str, dx: str, out: str) -> list[str]:
        """Lines setting ``out`` to ``z`` after displacement ``dx`` (after :meth:`rate_lines`)."""
        if not self.law:
            return bw_update_lines(z, dx, out, self.cst)
        return bw_update_lines(z, dx, out, self.cst, scale="gm",
                               alpha_scale="ga" if self.law_state else None)

    def rest(self, p: str, out: str) -> list[str]:
        """Lines setting ``out`` to the static equilibrium with ``z = 0`` at pressure ``p``."""
        k_e = f"{self.theta}[i, 4]"
        lines = [f"rhs = {self.actuator(p)}", f"{out} = rhs / {k_e}"]
        if self.force:  # static equilibrium with z = 0 under nonlinear force effects
            lines += ["for it in range(50):"]
            lines += ["    " + ln for ln in self.forces(out, "0.0", p, "fe", True)]
            lines += [
                f"    step = ({k_e} * {out} + fe - rhs) / ({k_e} + fe_x)",
                f"    {out} -= step",
                f"    if abs(step) <= 1e-15 * (1.0 + abs({out})):",
                "        break",
            ]
        return lines

    def step(self, p_start: str, p_end: str, x0: str, v0: str, z0: str,
             x1: str, v1: str, z1: str) -> list[str]:
        """Lines advancing the state over one step with pressure from ``p_start`` to ``p_end``."""
        c = self.cst
        step = []
        start, pred, slope = {}, {}, {}  # stateful effects: the start and predicted states
        for e, row in self.state_row.items():
            start[e], pred[e], slope[e] = f"sv{row}", f"sp{row}", f"sp{row}_d"
            step += [f"sv{row} = st[{row}, i]"]
            # the state at the step's end if x stayed put, and its slope in the end x
            step += self.advance(e, start[e], x0, x0, "dt / substeps", pred[e])
        step += [
            f"r0 = {z0} - {c}[8, i] * {x0}",
            f"fs = {self.actuator(p_start)}",
            f"fe = {self.actuator(p_end)}" if p_end != p_start else "fe = fs",
        ]
        if self.force:
            step += self.forces(x0, v0, p_end, "efs", True, z0, pred, slope)
            if p_end != p_start or start:
                step += self.forces(x0, v0, p_start, "ef0", False, z0, start)
            else:
                step += ["ef0 = efs"]
            step += ["g0 = fs - r0 - ef0", "gs = fe - r0 - efs"]
        else:
            step += ["g0 = fs - r0", "gs = fe - r0"]
        step += [
            f"xs = {c}[0, i] * {x0} + {c}[1, i] * {v0} + {c}[4, i] * g0 + {c}[6, i] * (gs - g0)",
            f"vs = {c}[2, i] * {x0} + {c}[3, i] * {v0} + {c}[5, i] * g0 + {c}[7, i] * (gs - g0)",
            f"dxs = xs - {x0}",
        ]
        g_last = f"st[{self.law_row}, i]" if self.law else "0.0"
        law_rows = ((f"st[{self.law_row + 1}, i]", f"st[{self.law_row + 2}, i]")
                    if self.law_state else None)
        step += self.rate_lines(z0, "dxs", g_last, law_rows)
        # The end-of-step force (z and effects) is linearly implicit; z then advances
        # exactly over the displacement dx, and x1 = x0 + dx keeps z and x consistent,
        # so the rate-independent hysteresis cannot drift.
        # s is the end-of-step increment of the remainder force r (and of the effects)
        if self.force:
            step += [
                f"ax = kz - {c}[8, i] + efs_x" + (" + efs_z * kz" if self.reads_z else ""),
                f"s = (ax * dxs + efs_v * (vs - {v0})) / (1.0 + {c}[6, i] * ax + {c}[7, i] "
                "* efs_v)",
                f"dx = dxs - {c}[6, i] * s",
            ]
            step += self.update_lines(z0, "dx", z1)
            if self.reads_z:  # the z-reading forces follow z's exact change too
                step += [f"s += (1.0 + efs_z) * (({z1} - {z0}) - kz * dx)"]
            else:
                step += [f"s += ({z1} - {z0}) - kz * dx"]
        else:
            step += [f"dx = dxs / (1.0 + {c}[6, i] * (kz - {c}[8, i]))"]
            step += self.update_lines(z0, "dx", z1)
            step += [f"s = {z1} - {z0} - {c}[8, i] * dx"]
        step += [f"{x1} = {x0} + dx", f"{v1} = vs - {c}[7, i] * s"]
        for e, row in self.state_row.items():
            step += self.advance(e, start[e], x0, f"{x0} + dx", "dt / substeps", f"sv{row}")
            step += [f"st[{row}, i] = sv{row}"]
        if self.law:
            step += [f"{g_last} = gm"]
        if self.law_state:  # the state over the step, z having run from z0 to z1
            e = self.law[0][0]
            step += [f"{law_rows[0]} = ga",
                     f"{law_rows[1]} = {self.name_of[e]}_adv({self.q(e)}[i], {law_rows[1]}, "
                     f"{z0}, {z1}, dx)"]
        return step


def _generate(model: Model, record: bool, shared_input: bool,
              between_samples: str = "hold", initial_state: str = "rest",
              resume: bool = False) -> tuple[str, dict]:
    """Source of the kernel for ``model`` and the globals it needs injected."""
    plant = PlantCode(model)
    zero = initial_state == "zero"
    # a given start (``init``: (3, batch)) is an argument only where it is used
    given = initial_state == "estimate"
    pressure, measure = plant.pressure, plant.measure
    name_of = plant.name_of

    args = ("theta, p_in, time_s, dt, substeps, mass, f_grav, area, "
            + ("init, " if given else "") + "out_x")
    if record:
        args += ", out_v, out_z, out_p, out_f, out_true"
    if resume:
        args += ", st_io, start, from_rest"
    # Few distinct arrays keep the vectoriser's runtime alias checks cheap: all
    # per-member constants live in rows of `cst`, the state in rows of `st`.
    body = ["n = out_x.shape[0]", "batch = theta.shape[0]"] + plant.setup()
    if resume:  # the plant starts at sample `start`, from st_io unless from_rest
        body += ["k0 = start * substeps" if between_samples == "bandlimited" else "k0 = start"]
    first = "k0" if resume else "0"
    loops = dict(zero=zero, resume=resume, given=given)
    # within a sample interval the pressure is linear from pp[0] to pp[1]
    linear = between_samples == "linear"
    body += [f"st = np.zeros(({plant.n_rows}, batch))"]
    if between_samples == "bandlimited":
        # p_in holds the reconstructed input at every substep boundary (fine index
        # k * substeps + j); each substep takes the straight line between two of them
        fine = "k * substeps + j"
        if shared_input and not pressure:
            body += _sample_loops(plant, record, "pa", "pb", "p_in[(k + 1) * substeps, 0]",
                                  f"p_in[{first}, 0]",
                                  substep_lines=[f"pa = p_in[{fine}, 0]",
                                                 f"pb = p_in[{fine} + 1, 0]"], **loops)
        else:
            body += (_pressure_fill(plant, shared_input, True, fine=True)
                     + _sample_loops(plant, record, f"pp[0, {fine}, i]", f"pp[1, {fine}, i]",
                                     "pp[0, (k + 1) * substeps, i]", f"pp[0, {first}, i]",
                                     **loops))
    else:
        ramps = bool(pressure) or linear
        via_pp = (
            "(pp[0, k, i] + (pp[1, k, i] - pp[0, k, i]) * fa)" if ramps else "pp[0, k, i]",
            "(pp[0, k, i] + (pp[1, k, i] - pp[0, k, i]) * fb)" if ramps else "pp[0, k, i]",
            "pp[0, k + 1, i]",
            f"pp[0, {first}, i]",
        )
        shared = ("pk", "pk", "p_in[k + 1, 0]", f"p_in[{first}, 0]")
        # one loop per kernel: a second copy in the same function does not vectorise
        if ramps or not shared_input:
            body += (_pressure_fill(plant, shared_input, linear)
                     + _sample_loops(plant, record, *via_pp, **loops))
        else:
            body += _sample_loops(plant, record, *shared, **loops)
    if record:
        body += ["out_true[:, :] = out_x"]
    body += [f"{name_of[e]}(theta[:, {s.start}:{s.stop}], time_s, out_x)" for e, s in measure]

    text = _HEADER.format(effects=", ".join(model.effect_names) or "none")
    text += f"# input shared by the batch: {shared_input}; recording states: {record}\n"
    text += f"# input between samples: {between_samples}\n"
    if zero or given:  # only then, so that the rest kernels' text (and disk cache) is unchanged
        text += f"# initial state: {initial_state}\n"
    if resume:
        text += "# resumes from a given state\n"
    text += f"FASTMATH = set({sorted(FASTMATH)!r})\n"
    for g in plant.inject:
        text += f"{g} = None  # injected before the first call\n"
    text += "\n\n@njit(cache=True, fastmath=FASTMATH, error_model='numpy')\n"
    text += f"def kernel({args}):\n"
    text += indent_lines(body, 4) + "\n"
    return text, plant.inject


def _pressure_fill(plant: PlantCode, shared_input: bool, linear: bool = False,
                   fine: bool = False) -> list[str]:
    """Lines that fill ``pp`` (the start and end pressure of each interval) from the
    input, held or linear between samples, and pass it through the pressure effects.

    With ``fine`` the input holds one value per substep boundary and each of ``pp``'s
    intervals is one substep, ``dt / substeps`` long.
    """
    rows = "p_in.shape[0]" if shared_input else "p_in.shape[1]"
    m = "m" if fine else "n"
    fill = [f"m = {rows}"] if fine else []
    fill += [
        f"pp = np.empty((2, {m}, batch))",
    ]
    if shared_input:  # p_in is (n, 1)
        fill += [f"for k in range({m}):", "    pp[0, k, :] = p_in[k, 0]"]
    else:  # p_in is (batch, n): transpose in cache-sized blocks
        fill += [
            f"for k0 in range(0, {m}, 64):",
            "    for i in range(batch):",
            f"        for k in range(k0, min(k0 + 64, {m})):",
            "            pp[0, k, i] = p_in[i, k]",
        ]
    fill += [
        "pp[1] = pp[0]",
    ]
    if linear:  # each interval ramps to the next sample
        fill += [f"for k in range({m} - 1):", "    pp[1, k, :] = pp[0, k + 1, :]"]
    step = "dt / substeps" if fine else "dt"
    fill += [
        f"{plant.name_of[e]}(theta[:, {s.start}:{s.stop}], pp[0], pp[1], {step})"
        for e, s in plant.pressure
    ]
    return fill


def _sample_loops(plant: PlantCode, record: bool, p_start: str, p_end: str, p_next: str,
                  p_first: str, substep_lines: tuple[str, ...] | list[str] = (),
                  zero: bool = False, resume: bool = False, given: bool = False
                  ) -> list[str]:
    """Lines of the initial state and the time loop, given how the pressure at the
    start and end of a substep, at the next sample and at the first is read
    (``substep_lines`` run once per substep, before the batch loop). The state starts
    at rest under the first input, with ``zero`` at ``x = x' = z = 0``, or with
    ``given`` at ``init[:, i]``: position, velocity, and ``z`` as an offset from the
    balance at that position and velocity (:meth:`PlantCode.balance`). With
    ``resume`` the plant starts at sample ``start`` from the state rows ``st_io`` (or as
    above where ``from_rest``), and leaves its final state there."""
    rest = ["xi = 0.0"] if zero else plant.rest("p0", "xi")
    out = ["for i in range(batch):", f"    p0 = {p_first}"]
    if resume:
        out += ["    if from_rest:"] + ["        " + ln for ln in rest]
        out += ["        st[0, i] = xi", "    else:",
                f"        for r in range({plant.n_rows}):", "            st[r, i] = st_io[r, i]",
                "    xi = st[0, i]", "    out_x[start, i] = xi"]
    elif given:
        out += ["    xi = init[0, i]", "    st[1, i] = init[1, i]"]
        out += ["    " + ln for ln in plant.balance("p0", "xi", "init[1, i]", "zi")]
        out += ["    st[2, i] = zi + init[2, i]"]
        out += ["    st[0, i] = xi", "    out_x[0, i] = xi"]
    else:
        out += ["    " + ln for ln in rest]
        out += ["    st[0, i] = xi", "    out_x[0, i] = xi"]
    k0 = "start" if resume else "0"
    if record:
        states = {e: f"st[{row}, i]" for e, row in plant.state_row.items()}
        if resume or given:
            out += [f"    out_v[{k0}, i] = st[1, i]", f"    out_z[{k0}, i] = st[2, i]",
                    f"    out_p[{k0}, i] = p0"]
        else:
            out += ["    out_v[0, i] = 0.0", "    out_z[0, i] = 0.0", "    out_p[0, i] = p0"]
        out += ["    " + ln for ln in (
            plant.forces("xi", "st[1, i]", "p0", "f0", False, "st[2, i]", states) if resume
            else plant.forces("xi", "st[1, i]", "p0", "f0", False, "st[2, i]") if given
            else plant.forces("xi", "0.0", "p0", "f0", False))]
        out += [f"    out_f[{k0}, i] = f0"]
    step = ["x0 = st[0, i]; v0 = st[1, i]; z0 = st[2, i]"]
    step += plant.step(p_start, p_end, "x0", "v0", "z0", "x1", "v1", "z1")
    step += ["st[0, i] = x1; st[1, i] = v1; st[2, i] = z1"]
    sample = ["out_x[k + 1, i] = st[0, i]"]
    if record:
        sample += [
            "out_v[k + 1, i] = st[1, i]",
            "out_z[k + 1, i] = st[2, i]",
            f"out_p[k + 1, i] = {p_next}",
        ]
        sample += plant.forces("st[0, i]", "st[1, i]", p_next, "fn", False, "st[2, i]",
                               {e: f"st[{row}, i]" for e, row in plant.state_row.items()})
        sample += ["out_f[k + 1, i] = fn"]
    out += ["for k in range(start, n - 1):" if resume else "for k in range(n - 1):"]
    if p_start == "pk":
        out += ["    pk = p_in[k, 0]"]
    out += [
        "    for j in range(substeps):",
        "        fa = j / substeps",
        "        fb = (j + 1) / substeps",
    ]
    out += ["        " + ln for ln in substep_lines]
    out += [
        "        for i in range(batch):",
    ]
    out += ["            " + ln for ln in step]
    out += ["    for i in range(batch):"]
    out += ["        " + ln for ln in sample]
    if resume:
        out += [f"for r in range({plant.n_rows}):", "    for i in range(batch):",
                "        st_io[r, i] = st[r, i]"]
    return out


def cache_dir() -> Path:
    """Directory for generated kernels.

    Returns
    -------
    Path
        ``$PMABAYES_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/pmabayes`` or
        ``~/.cache/pmabayes``.
    """
    env = os.environ.get("PMABAYES_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "pmabayes"


_KERNELS: dict[tuple, object] = {}
_LOCK = threading.Lock()


def structure_key(model: Model, record: bool, shared_input: bool,
                  between_samples: str = "hold", initial_state: str = "rest",
                  resume: bool = False) -> tuple:
    """Key of a kernel's composition: the effects (by identity), the input kind, the
    rig values identified as parameters, and the conventions of the input between
    samples and of the initial state."""
    key = (
        tuple((e.__module__, e.__qualname__, id(e)) for e in model.effects),
        model.rig.input_kind,
        record,
        shared_input,
    )
    key = key if between_samples == "hold" else (*key, between_samples)
    if model.rig_columns:
        key = (*key, "rig", tuple(sorted(model.rig_columns.items())))
    if resume:
        key = (*key, "resume")
    return key if initial_state == "rest" else (*key, "initial_state", initial_state)


def kernel_for(model: Model, *, record: bool = False, shared_input: bool = True,
               between_samples: str = "hold", initial_state: str = "rest",
               resume: bool = False):
    """The compiled kernel for ``model``'s composition (generated and cached once).

    Parameters
    ----------
    model : Model
        The composed model; only its effects and input kind matter.
    record : bool
        Whether the kernel also records velocity, ``z``, acting pressure and effect
        force at every sample.
    shared_input : bool
        Whether one input signal, passed as ``(n, 1)``, drives the whole batch, or
        each member has its own row of a ``(batch, n)`` array.
    between_samples : str
        What the input does between samples: ``"hold"``, ``"linear"`` or
        ``"bandlimited"``; for the last, ``p_in`` holds the reconstructed input at every
        substep boundary, ``(n - 1) * substeps + 1`` values.
    initial_state : str
        ``"rest"`` (static equilibrium under the first input, ``x' = z = 0``) or
        ``"zero"`` (``x = x' = z = 0``); see :data:`INITIAL_STATES`.
    resume : bool
        The kernel takes three more arguments, ``st_io, start, from_rest``: the plant
        starts at sample ``start`` from the state rows ``st_io`` (``(rows, batch)``;
        or from ``initial_state`` where ``from_rest``) and writes its final state
        back there. The input before ``start`` only drives the pressure effects.

    Returns
    -------
    numba dispatcher
        ``kernel(theta, p_in, time_s, dt, mass, f_grav, area, out_x[, ...])``.
    """
    if initial_state not in INITIAL_STATES:
        raise SimulationError(
            f"initial_state must be one of {', '.join(map(repr, INITIAL_STATES))}, got "
            f"{initial_state!r}")
    key = structure_key(model, record, shared_input, between_samples, initial_state, resume)
    kernel = cached_kernel(key)
    if kernel is not None:
        return kernel
    text, inject = _generate(model, record, shared_input, between_samples, initial_state,
                             resume)
    return compile_kernel(key, text, inject)


def cached_kernel(key: tuple):
    """The kernel compiled under ``key`` in this process, or None (check before generating)."""
    with _LOCK:
        return _KERNELS.get(key)


def _disk_cached(folder: Path, modname: str) -> bool:
    """Whether numba's disk cache holds compiled code of the generated module ``modname``
    (its index file, beside the source or under ``NUMBA_CACHE_DIR``)."""
    places = [folder / "__pycache__"]
    if numba.config.CACHE_DIR:
        places.append(Path(numba.config.CACHE_DIR))
    return any(next(p.rglob(f"{modname}.*.nbi"), None) is not None
               for p in places if p.is_dir())


def compile_kernel(key: tuple, text: str, inject: dict, name: str = "kernel",
                   what: str = "the simulator for this model"):
    """Compile generated source (module-level function ``name``), cached on disk and in memory.

    Shared by every generated kernel (here and in :mod:`pmabayes.control`); the file
    name hashes the source, the helpers it calls and the library versions, so a
    change to any of them compiles afresh. numba compiles at the first call; where
    its disk cache holds nothing for this source yet, that is said first
    (``compiling WHAT (cached after)``), since it takes seconds.
    """
    with _LOCK:
        if key in _KERNELS:
            return _KERNELS[key]
        digest = fingerprint(text, source_text(_discretise),
                             *(source_text(f) for f in inject.values()),
                             numba.__version__, np.__version__, sys.version, length=20)
        modname = f"pmabayes_kernel_{digest}"
        folder = cache_dir() / "kernels"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{modname}.py"
            if not path.exists() or path.read_text() != text:
                fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
                with os.fdopen(fd, "w") as fh:
                    fh.write(text)
                os.replace(tmp, path)
        except OSError:  # read-only home: compile in a private temporary folder
            folder = Path(tempfile.mkdtemp(prefix="pmabayes-kernels-"))
            path = folder / f"{modname}.py"
            path.write_text(text)
        if not _disk_cached(folder, modname):
            Progress().say(f"compiling {what} (cached after)")
        spec = importlib.util.spec_from_file_location(modname, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[modname] = module  # numba's cache re-imports the module by name
        spec.loader.exec_module(module)
        for g, fn in inject.items():
            setattr(module, g, fn)
        _KERNELS[key] = getattr(module, name)
        return _KERNELS[key]


# ---------------------------------------------------------------------------------
# Python API


@dataclass(frozen=True)
class Simulation:
    """Recorded states of a simulation, each ``(batch, n_samples)``.

    Parameters
    ----------
    time_s : numpy.ndarray
        Sample times, ``(n_samples,)``.
    position_m : numpy.ndarray
        Position as measured (after measurement effects).
    true_position_m : numpy.ndarray
        Position before measurement effects.
    velocity_m_s : numpy.ndarray
        Velocity.
    hysteresis_n : numpy.ndarray
        Bouc-Wen force ``z``.
    pressure_pa : numpy.ndarray
        Input acting on the actuator at each sample time (after pressure effects):
        pressure in Pa, or force in N for a force-driven rig.
    effect_force_n : numpy.ndarray
        Sum of the force effects at each sample.
    """

    time_s: np.ndarray
    position_m: np.ndarray
    true_position_m: np.ndarray
    velocity_m_s: np.ndarray
    hysteresis_n: np.ndarray
    pressure_pa: np.ndarray
    effect_force_n: np.ndarray


def _time_axis(n: int, dt_s: float | None, time_s: np.ndarray | None) -> tuple[np.ndarray, float]:
    if time_s is not None:
        time_s = np.asarray(time_s, dtype=float)
        if time_s.shape != (n,):
            raise SimulationError(f"time_s has shape {time_s.shape}, expected ({n},)")
        dt = (check_time_grid(time_s, source="simulate", error=SimulationError) if n > 1
              else (dt_s or 1.0))
        if dt_s is not None and abs(dt - dt_s) > 1e-9 * dt:
            raise SimulationError(f"dt_s={dt_s} disagrees with the spacing of time_s ({dt})")
        return time_s, dt
    if dt_s is None or not dt_s > 0:
        raise SimulationError("give dt_s > 0 (the sample interval in s) or time_s")
    return np.arange(n) * float(dt_s), float(dt_s)


#: Default tolerance of the periodic steady state in m: the position over a period
#: from the state found differs from that over the next period by at most this.
STEADY_STATE_TOL_M = 1e-9
#: Default most periods simulated to find the state of a record that starts in
#: periodic steady state.
MAX_WARMUP_PERIODS = 256
#: Degree of the interpolating spline that reconstructs a band-limited input that is
#: not declared periodic (odd, so its knots sit on the samples).
SPLINE_DEGREE = 9

_FINE: dict[tuple, np.ndarray] = {}  # reconstructed inputs, keyed by content
_FINE_MAX = 8


def _fine_periodic(u: np.ndarray, substeps: int) -> np.ndarray:
    """Trigonometric interpolation of ``u`` (period: its whole length) at ``substeps``
    points per sample interval; ``(..., n * substeps)``, exact for a periodic input
    without content at the Nyquist frequency."""
    n = u.shape[-1]
    spec = np.fft.rfft(u, axis=-1)
    fine = np.zeros((*u.shape[:-1], n * substeps // 2 + 1), dtype=complex)
    fine[..., : n // 2 + 1] = spec
    if n % 2 == 0:  # the Nyquist line is a cosine: split it between +- fs / 2
        fine[..., n // 2] *= 0.5
    return np.fft.irfft(fine, n * substeps, axis=-1) * substeps


def _fine_spline(u: np.ndarray, substeps: int) -> np.ndarray:
    """Degree-``SPLINE_DEGREE`` interpolating spline of ``u`` at ``substeps`` points per
    sample interval, ``(..., (n - 1) * substeps + 1)``; not-a-knot ends."""
    from scipy.interpolate import make_interp_spline

    n = u.shape[-1]
    degree = min(SPLINE_DEGREE, n - 1)
    degree -= 1 - degree % 2  # odd
    spline = make_interp_spline(np.arange(n, dtype=float), u, k=degree, axis=-1)
    return spline(np.arange((n - 1) * substeps + 1) / substeps)


def _fine_input(u: np.ndarray, substeps: int, periodic: bool) -> np.ndarray:
    """Band-limited reconstruction of ``u`` at every substep boundary, memoised by
    content (a likelihood simulates the same input many times)."""
    key = (fingerprint(u.tobytes(), str(u.shape), length=20), substeps, periodic)
    with _LOCK:
        hit = _FINE.get(key)
    if hit is not None:
        return hit
    n = u.shape[-1]
    if substeps == 1:
        fine = u.copy()
    elif periodic:
        fine = _fine_periodic(u, substeps)[..., : (n - 1) * substeps + 1]
    else:
        fine = _fine_spline(u, substeps)
    fine[..., ::substeps] = u  # the samples themselves, not their rounding
    fine.flags.writeable = False
    with _LOCK:
        if len(_FINE) >= _FINE_MAX:
            _FINE.pop(next(iter(_FINE)))
        _FINE[key] = fine
    return fine


def _kernel_input(u: np.ndarray, substeps: int, between_samples: str, period: int | None,
                  warmup: int) -> np.ndarray:
    """The array the kernel reads: the samples, or the band-limited reconstruction at
    every substep boundary; preceded by ``warmup`` copies of the first period."""
    if between_samples != "bandlimited":
        if warmup:
            u = np.concatenate([np.tile(u[..., :period], warmup), u], axis=-1)
        return u
    if not warmup:
        return _fine_input(u, substeps, period is not None)
    one = _fine_periodic(u[..., :period], substeps) if substeps > 1 else u[..., :period]
    # the record is the same periodic signal (whole periods, or one period and its next
    # sample): the period's reconstruction, repeated
    m = (u.shape[-1] - 1) * substeps + 1
    fine = np.tile(one, (1,) * (u.ndim - 1) + (-(-m // one.shape[-1]),))[..., :m]
    fine[..., ::substeps] = u
    return np.concatenate([np.tile(one, warmup), fine], axis=-1)


def _check_period(period_samples, steady_state, n: int) -> int | None:
    if not isinstance(steady_state, bool | np.bool_):
        raise SimulationError(f"steady_state must be True or False, got {steady_state!r}")
    if period_samples is None:
        if steady_state:
            raise SimulationError(
                "steady_state=True needs period_samples (the samples in one period of the "
                "periodic input): a steady state exists only for a periodic input")
        return None
    if not (isinstance(period_samples, int | np.integer) and not isinstance(period_samples, bool)
            and period_samples >= 2):
        raise SimulationError(
            f"period_samples must be an integer >= 2 (samples in one period), got "
            f"{period_samples!r}")
    if n % period_samples:
        raise SimulationError(
            f"period_samples={period_samples} does not divide the input's {n} samples "
            f"({n / period_samples:.4g} periods); pass whole periods only")
    return int(period_samples)


def simulate(
    model: Model,
    params=None,
    input_signal=None,
    *,
    dt_s: float | None = None,
    time_s: np.ndarray | None = None,
    substeps: int = 1,
    states: bool = False,
    between_samples: str = "hold",
    period_samples: int | None = None,
    steady_state: bool = False,
    steady_state_tol_m: float = STEADY_STATE_TOL_M,
    max_warmup_periods: int = MAX_WARMUP_PERIODS,
    initial_state: str = "rest",
    initial_values=None,
):
    """Simulate ``model`` for a batch of parameter sets.

    Parameters
    ----------
    model : Model
        The composed model.
    params : mapping or array, optional
        Parameters, as accepted by :meth:`Model.theta` (defaults if None). A batch
        of ``B`` parameter sets gives ``B`` simulations.
    input_signal : array_like
        Commanded pressure in Pa (force in N for a force-driven rig), shape
        ``(n_samples,)`` shared by the batch or ``(B, n_samples)``.
    dt_s : float, optional
        Sample interval in s (or give ``time_s``).
    time_s : array_like, optional
        Uniform sample times, shape ``(n_samples,)``.
    substeps : int
        Integration steps per sample interval (the input is held, or interpolated
        after pressure effects). 1 is accurate to better than 1e-6 m for the PMA at
        1 kHz. A lightly damped oscillator whose hysteretic stiffness is comparable
        to its spring and whose response nears the sample rate needs more. The error
        falls as ``substeps**-2``; see the README.
    states : bool
        Return a :class:`Simulation` with all recorded states instead of positions.
    between_samples : str
        What the input does between samples (see :data:`BETWEEN_SAMPLES`):
        ``"hold"`` (the default: a DAQ's zero-order hold of a commanded pressure,
        each sample acting until the next); ``"linear"`` (straight lines between
        samples); or ``"bandlimited"`` (the samples of a continuous band-limited
        signal, such as a measured pressure or a generated multisine). A
        band-limited input is reconstructed at every substep boundary, and each
        substep takes the straight line between two of those values: by
        trigonometric (FFT) interpolation of the record when ``period_samples`` is
        given (exact for a periodic input), otherwise by a degree-9 interpolating
        spline with not-a-knot ends (near the first and last few samples it is the
        polynomial through the end samples, less accurate than inside). Give it
        substeps: with ``substeps=1`` it is ``"linear"``. With pressure effects or
        per-member inputs the kernel keeps the reconstruction per member (16 bytes
        per substep and member).
    period_samples : int, optional
        Samples in one period, when the input is whole periods of a periodic signal
        (it must divide ``n_samples``). Used by ``"bandlimited"`` and
        ``steady_state``.
    steady_state : bool
        The record starts in periodic steady state of its first period, repeated
        (reached from ``initial_state``): the record starts from that state, after
        one period that settles the pressure effects. False (default): the record
        starts from ``initial_state``.
    steady_state_tol_m : float
        Tolerance of the steady state in m (default :data:`STEADY_STATE_TOL_M`): the
        position over a period from the state found differs from that over the next
        period by at most this.
    max_warmup_periods : int
        Most periods simulated to find the steady state (default
        :data:`MAX_WARMUP_PERIODS`). It is found by Newton's method on the period map
        (the state after one period from a state at the period's start), a few
        steps of ``rows + 2`` periods each, where simulating period after period
        from rest needs as many periods as the transient is slow (the muscle's
        hysteresis shakes down by about 0.84 a period, slower on short periods). If
        the tolerance is not reached, a :class:`SteadyStateWarning` says by how much,
        and the record starts from the last state.
    initial_state : str
        The state each trial (or its warm-up, with ``steady_state``) starts from (see
        :data:`INITIAL_STATES`): ``"rest"`` (the default: ``x' = 0``, ``z = 0`` and
        ``x`` at static equilibrium under the first input sample, as after a long
        hold of it) or ``"zero"`` (``x = x' = z = 0`` whatever the first input: a
        plant at rest at zero input that the input switches on at the first sample,
        as the Bouc-Wen benchmark's simulations start) or ``"estimate"`` (the state
        ``initial_values`` gives). Pressure effects start as under ``"rest"``.
    initial_values : array_like, optional
        With ``initial_state="estimate"`` (and only then): each member's start,
        ``(3,)`` shared or ``(B, 3)``: the position in m (before measurement effects),
        the velocity in m/s, and the hysteretic force ``z`` in N as an offset from the
        balance at that position and velocity (the ``z`` at which the actuator, spring,
        damper and force effects leave no acceleration; 0 starts from that balance).
        Force effects' own states start at 0.

    Returns
    -------
    numpy.ndarray or Simulation
        Positions in m, shape ``(B, n_samples)``; or the recorded states.

    Raises
    ------
    SimulationError
        On inconsistent shapes, a bad time axis, non-finite inputs or a bad period.
    ModelError
        On bad parameters (unknown names, out of bounds).
    """
    if input_signal is None:
        raise SimulationError("input_signal is required (pressure in Pa or force in N)")
    if between_samples not in BETWEEN_SAMPLES:
        raise SimulationError(
            f"between_samples must be one of {', '.join(map(repr, BETWEEN_SAMPLES))}, got "
            f"{between_samples!r}")
    if not (isinstance(substeps, int | np.integer) and substeps >= 1):
        raise SimulationError(f"substeps must be an integer >= 1, got {substeps!r}")
    if initial_state not in INITIAL_STATES:
        raise SimulationError(
            f"initial_state must be one of {', '.join(map(repr, INITIAL_STATES))}, got "
            f"{initial_state!r}")
    theta = model.theta(params)
    u = np.asarray(input_signal, dtype=float)
    if not (u.ndim == 1 or (u.ndim == 2 and u.shape[0] == theta.shape[0])):
        raise SimulationError(
            f"input_signal has shape {u.shape}; expected (n_samples,) or "
            f"({theta.shape[0]}, n_samples) for a batch of {theta.shape[0]}"
        )
    if not np.all(np.isfinite(u)):
        raise SimulationError("input_signal contains NaN or inf")
    n = u.shape[-1]
    if n < 2:
        raise SimulationError("need at least 2 samples")
    if steady_state:
        if not steady_state_tol_m > 0:
            raise SimulationError(f"steady_state_tol_m must be > 0, got {steady_state_tol_m!r}")
        if not (isinstance(max_warmup_periods, int | np.integer) and max_warmup_periods >= 3):
            raise SimulationError(
                f"max_warmup_periods must be an integer >= 3, got {max_warmup_periods!r}")
    t, dt = _time_axis(n, dt_s, time_s)
    init = _initial_values(initial_state, initial_values, theta.shape[0], steady_state)
    return _simulate_on_grid(model, theta, u, t, dt, substeps=int(substeps), states=states,
                             between_samples=between_samples,
                             period=_check_period(period_samples, steady_state, n),
                             steady_state=steady_state, steady_state_tol_m=steady_state_tol_m,
                             max_warmup_periods=max_warmup_periods,
                             initial_state=initial_state, init=init)


def _initial_values(initial_state: str, values, batch: int, steady_state: bool
                    ) -> np.ndarray | None:
    """The kernel's ``init`` ``(3, batch)`` for a given start, checked; None otherwise."""
    if initial_state != "estimate":
        if values is not None:
            raise SimulationError(
                f"initial_values are the start of initial_state='estimate'; with "
                f"initial_state={initial_state!r} the start is fixed: leave them out")
        return None
    if steady_state:
        raise SimulationError("initial_state='estimate' gives the record's start, which a "
                              "steady state would replace: use one or the other")
    if values is None:
        raise SimulationError(
            "initial_state='estimate' needs initial_values: (position m, velocity m/s, "
            "z offset N) per member, (3,) or (batch, 3)")
    v = np.asarray(values, dtype=float)
    if v.shape == (3,):
        v = np.broadcast_to(v, (batch, 3))
    if v.shape != (batch, 3):
        raise SimulationError(f"initial_values must be 3 values, or ({batch}, 3) for a batch "
                              f"of {batch}; got shape {v.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if bad.size:
        shown = ", ".join(str(i) for i in bad[:10]) + (", ..." if bad.size > 10 else "")
        raise SimulationError(
            f"initial_values must be finite: {bad.size} of {batch} rows are not (rows "
            f"{shown}; first {v[bad[0]].tolist()} as position m, velocity m/s, z offset N)")
    return np.ascontiguousarray(v.T)


def _simulate_on_grid(model: Model, theta: np.ndarray, u: np.ndarray, t: np.ndarray,
                      dt: float, *, substeps: int, states: bool, between_samples: str,
                      period: int | None, steady_state: bool, steady_state_tol_m: float,
                      max_warmup_periods: int, initial_state: str,
                      init: np.ndarray | None = None):
    """:func:`simulate` on a checked input and time grid (the data set's own, checked
    when it was made: the sampler calls this thousands of times)."""
    run = dict(model=model, theta=theta, u=u, t=t, dt=dt, substeps=substeps,
               between_samples=between_samples, period=period, initial_state=initial_state)
    if init is not None:  # a given start (never with a steady state)
        run["init"] = init
    if not steady_state:
        return _run(**run, states=states)
    start = _steady_state(run, float(steady_state_tol_m), int(max_warmup_periods))
    # the record from the periodic state, after one period that settles the pressure path
    return _run(**run, states=states, lead=1, state=start)


#: The early stop of a steady-state search that cannot settle (:func:`_steady_state`): a
#: member whose change over a period has shrunk by a steady ratio (within this factor
#: of each other) over this many iterations, and which at its fastest ratio would need
#: more than this multiple of the budget, gives up. Chosen on the searches of 2800
#: parameter sets around the plausible muscle (a 1 Hz sine, 5000 samples a period):
#: no member that settles within the budget gives up; the others cost about half.
TREND_ITERATIONS, TREND_SPREAD, TREND_MARGIN = 6, 1.1, 2.0


def _beyond_budget(trail: np.ndarray, used: int, budget: int, tol: float, cost: int
                   ) -> np.ndarray:
    """Which members' changes (``trail``: ``(TREND_ITERATIONS + 1, members)``, the last
    iterations' changes, the newest last; NaN before a member's first) have shrunk by
    a steady ratio and project beyond :data:`TREND_MARGIN` times the budget, at the
    fastest ratio seen and ``cost`` periods an iteration."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = trail[1:] / trail[:-1]
        fastest, slowest = ratio.min(axis=0), ratio.max(axis=0)
        steady = np.all(np.isfinite(ratio), axis=0) & (slowest <= TREND_SPREAD * fastest)
        needed = np.where(fastest < 1.0, np.log(tol / trail[-1]) / np.log(fastest), np.inf)
    return steady & (used + needed * cost > TREND_MARGIN * budget)


def _steady_state(run: dict, tol: float, budget: int) -> np.ndarray:
    """The state at the start of a period in periodic steady state, ``(rows, B)``.

    Newton's method on the period map ``P`` (the state after one period from a state
    at the period's start): from the state after one period from rest, each step
    solves ``(I - J) ds = P(s) - s`` with ``J`` the map's Jacobian by finite
    differences (one period per state row, the batch side by side). A member is
    done when its position over a period differs from that over the period before
    by at most ``tol``. This finds the state in a few steps where simulating period
    after period needs as many as the transient is slow (the muscle's hysteresis
    shakes down by a factor of about 0.84 a period, slower on short periods). A
    member whose step does not shrink its change is advanced period by period
    instead. ``budget`` bounds the periods simulated per member (Newton's steps
    count ``rows + 2`` each). A member whose change has shrunk by a steady ratio
    over :data:`TREND_ITERATIONS` steps, too slowly to settle within
    :data:`TREND_MARGIN` times the budget (a change that stays put: a drift that
    has no periodic state), stops there. A member that did not settle starts the
    record from its last state, and a :class:`SteadyStateWarning` counts them (one
    for a whole command within :func:`collect_steady_state_misses`).
    """
    period = run["period"]
    batch = run["theta"].shape[0]
    state = _periods(run, None, np.arange(batch))[1]
    rows = state.shape[0]
    change = np.full(batch, np.inf)
    previous = np.full(batch, np.inf)
    trail = np.full((TREND_ITERATIONS + 1, batch), np.nan)
    gave_up = np.zeros(batch, dtype=bool)
    left = np.arange(batch)
    used = 1
    while left.size and used + 2 <= budget:
        s0 = state[:, left]
        x1, s1 = _periods(run, s0, left)
        x2, s2 = _periods(run, s1, left)
        used += 2
        delta = np.max(np.abs(x2 - x1), axis=1)
        change[left] = delta
        trail[:-1] = trail[1:]
        trail[-1] = np.nan
        trail[-1, left] = delta
        going = (delta > tol) & np.isfinite(delta)  # a failed simulation stops too
        # one that cannot settle in time stops here, from its last state
        hopeless = going & _beyond_budget(trail[:, left], used, budget, tol, rows + 2)
        gave_up[left[hopeless]] = True
        going &= ~hopeless
        state[:, left] = np.where(going, s0, s2)  # a settled member starts at P(P(s))
        left, s0, s1, s2, delta = (left[going], s0[:, going], s1[:, going], s2[:, going],
                                   delta[going])
        if not left.size:
            break
        if used + rows + 2 > budget:  # no budget for a Newton step: one plain one
            state[:, left] = s2
            continue
        residual = s1 - s0  # P(s) - s
        h = 1e-7 * (np.abs(s0) + np.abs(residual)) + 1e-15
        perturbed = np.repeat(s0[:, None, :], rows, axis=1)  # (rows, rows, members)
        for j in range(rows):
            perturbed[j, j] += h[j]
        pj = _periods(run, perturbed.reshape(rows, -1), np.tile(left, rows))[1]
        used += rows
        jac = (pj.reshape(rows, rows, -1) - s1[:, None, :]) / h[None, :, :]
        step = residual.copy()
        for m in range(left.size):  # Newton: (I - J) ds = P(s) - s
            try:
                step[:, m] = np.linalg.solve(np.eye(rows) - jac[:, :, m], residual[:, m])
            except np.linalg.LinAlgError:
                pass
        step[:, ~np.all(np.isfinite(step), axis=0)] = 0.0
        # a member whose last Newton step did not halve its change goes on from
        # P(P(s)) instead (plain iteration), then tries Newton again
        stalled = delta > 0.5 * previous[left]
        previous[left] = delta
        state[:, left] = np.where(stalled, s2, s0 + step)
    missed = ~(change <= tol)
    if missed.any():
        finite = change[missed & np.isfinite(change)]
        _miss(SteadyMisses(batch, int(missed.sum()), int((gave_up & missed).sum()),
                           float(finite.max()) if finite.size else np.nan, budget, period,
                           tol))
    return state


@dataclass
class SteadyMisses:
    """A tally of members whose periodic steady state was not found (see
    :func:`collect_steady_state_misses`)."""

    members: int
    missed: int
    gave_up: int
    worst_m: float
    budget: int
    period: int
    tol: float

    def add(self, other: SteadyMisses) -> None:
        """Count ``other``'s members in this tally."""
        self.members += other.members
        self.missed += other.missed
        self.gave_up += other.gave_up
        self.worst_m = float(np.fmax(self.worst_m, other.worst_m))
        self.budget, self.period, self.tol = other.budget, other.period, other.tol

    def message(self) -> str:
        """What the warning says."""
        early = (f" ({self.gave_up} of them stopped before: their change shrank too slowly "
                 f"to settle within {TREND_MARGIN:g} times that, or not at all, a drift "
                 "from period to period)" if self.gave_up else "")
        worst = ("" if not np.isfinite(self.worst_m) else
                 f"; the position over the last period still changed by up to "
                 f"{self.worst_m:.3g} m")
        return (f"simulate: {self.missed} of {self.members} parameter sets found no periodic "
                f"steady state within {self.tol:g} m after {self.budget} warm-up periods of "
                f"{self.period} samples{early}{worst}. They start from their last state; "
                "raise max_warmup_periods or steady_state_tol_m (the data's sidecar, or "
                "pmabayes fit --max-warmup-periods / --steady-state-tol) if the fitted ones "
                "are among them.")


_COLLECTING: list = []  # [(pid, SteadyMisses or None)] while collect_steady_state_misses runs
_ONCE_IN_WORKER = [False]


def _miss(tally: SteadyMisses) -> None:
    """Say, or count, a steady-state search's members that did not settle."""
    with _LOCK:
        if _COLLECTING and _COLLECTING[-1][0] == os.getpid():
            pid, total = _COLLECTING[-1]
            if total is None:
                _COLLECTING[-1] = (pid, tally)
            else:
                total.add(tally)
            return
        # a forked worker of a collecting command: said once in this process
        if _COLLECTING:
            if _ONCE_IN_WORKER[0]:
                return
            _ONCE_IN_WORKER[0] = True
    warnings.warn(tally.message(), SteadyStateWarning, stacklevel=4)


@contextlib.contextmanager
def collect_steady_state_misses():
    """Count the members that find no periodic steady state, and say so once, at the end.

    Within it, :func:`simulate` does not warn for each batch whose members did not
    settle; one :class:`SteadyStateWarning` at the end counts them all (the command
    line runs every command within it). A worker process forked within it says so
    once itself.

    Yields
    ------
    None
    """
    with _LOCK:
        _COLLECTING.append((os.getpid(), None))
    try:
        yield
    finally:
        with _LOCK:
            tally = _COLLECTING.pop()[1]
        if tally is not None:
            warnings.warn(tally.message(), SteadyStateWarning, stacklevel=3)


def _periods(run: dict, state: np.ndarray | None, members: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Positions over the first period of the input from ``state`` (rest where None),
    after a lead period for the pressure path, and the state after it, for the batch
    members ``members``."""
    period = run["period"]
    u = run["u"]
    u = u[:period] if u.ndim == 1 else u[members, :period]
    # the period and the next one's first sample: the state at the next period's start
    u = np.ascontiguousarray(np.concatenate([u, u[..., :1]], axis=-1))
    sub = dict(run, theta=np.ascontiguousarray(run["theta"][members]), u=u,
               t=run["t"][0] + run["dt"] * np.arange(period + 1))
    x, final = _run(**sub, states=False, lead=1, state=state, periodic_input=True)
    return x[:, :period], final


def _run(*, model: Model, theta: np.ndarray, u: np.ndarray, t: np.ndarray, dt: float,
         substeps: int, states: bool, between_samples: str, period: int | None,
         initial_state: str = "rest", lead: int = 0, state: np.ndarray | None = None,
         periodic_input: bool = False, init: np.ndarray | None = None):
    """One kernel call over the record, after ``lead`` periods of its first period that
    only drive the pressure path.

    Returns the positions ``(B, n)`` (or the :class:`Simulation`) of the record; with a
    lead, the plant starts after it from ``state`` (``(rows, B)``; rest where None),
    and for ``periodic_input`` (the input is whole periods) ``(positions, final
    state)``.
    """
    n = u.shape[-1]
    p_in = _kernel_input(u, substeps, between_samples, period, lead)
    shared = u.ndim == 1
    p_in = np.ascontiguousarray(p_in[:, None] if shared else p_in)
    ahead = lead * (period or 0)
    if ahead:
        t = np.concatenate([t[0] + dt * np.arange(-ahead, 0), t])
    rig = model.rig
    batch = theta.shape[0]
    out_x = np.zeros((n + ahead, batch)) if lead else np.empty((n + ahead, batch))
    args = (theta, p_in, t, dt, substeps, rig.moving_mass_kg, rig.gravity_force_n,
            rig.area_m2, *(() if init is None else (init,)), out_x)
    kernel = dict(shared_input=shared, between_samples=between_samples,
                  initial_state=initial_state, resume=bool(lead))
    rows = state_rows(model) if lead else 0
    io = (np.array(state, dtype=float, order="C") if state is not None
          else np.zeros((rows, batch)))
    extra = (io, ahead, state is None) if lead else ()
    if not states:
        kernel_for(model, **kernel)(*args, *extra)
        _say_overflow(model, theta, dt / substeps, out_x[-1])
        x = out_x.T[:, ahead:]
        return (x, io) if periodic_input else x
    rec = [np.zeros((n + ahead, batch)) for _ in range(5)]
    kernel_for(model, record=True, **kernel)(*args, *rec, *extra)
    _say_overflow(model, theta, dt / substeps, out_x[-1])
    v, z, p, f, true_x = (a.T[:, ahead:] for a in rec)
    return Simulation(t[ahead:], out_x.T[:, ahead:], true_x, v, z, p, f)


class SteadyStateWarning(RuntimeWarning):
    """The periodic steady state was not reached within the warm-up allowed."""


class OverflowingStepWarning(RuntimeWarning):
    """A parameter set's exact step of the moving mass overflows (said once a process)."""


_OVERFLOW_SAID = [False]


def _say_overflow(model: Model, theta: np.ndarray, h: float, last: np.ndarray) -> None:
    """Warn, once a process, where a member's simulation is not finite because the exact
    step of its mass-spring-damper (:func:`_discretise`, step ``h``) overflows: a
    stiffness or damping so large over the moving mass that the step's matrix
    exponential is not finite. ``last`` is the members' final positions."""
    bad = np.flatnonzero(~np.isfinite(last))
    if _OVERFLOW_SAID[0] or not bad.size:
        return
    col = model.rig_columns.get("moving_mass_kg")
    coefficients = np.empty(8)
    for i in bad:
        mass = model.rig.moving_mass_kg if col is None else float(theta[i, col])
        stiffness = float(theta[i, 4] + theta[i, 0])
        _discretise(mass, float(theta[i, 3]), stiffness, h, coefficients)
        if np.all(np.isfinite(coefficients)):
            continue  # non-finite for another reason: the likelihood's -inf covers it
        _OVERFLOW_SAID[0] = True
        warnings.warn(
            f"simulate: a parameter set with damping d = {theta[i, 3]:.4g} N s/m and "
            f"stiffness K_e + alpha = {stiffness:.4g} N/m on a moving mass of {mass:.4g} kg "
            f"has no finite step of {h:.4g} s: its stiffness or damping over the mass "
            "overflows. Such parameter sets simulate to NaN and a likelihood gives them "
            "-inf (said once; a prior that allows such values is far wider than any muscle).",
            OverflowingStepWarning, stacklevel=2)
        return


#: How a data set's positions are referred, as a sidecar's ``position_reference``
#: declares it: ``"absolute"`` (the default: positions from the model's zero, the
#: unloaded length, up to any ``position_offset``) or ``"start"`` (the sensor was
#: zeroed with the actuator at rest at the record's start: the model's position at
#: the first sample is subtracted from its trajectory).
POSITION_REFERENCES = ("absolute", "start")


def warmup_settings(dataset, steady_state_tol_m: float | None = None,
                    max_warmup_periods: int | None = None) -> tuple[float, int]:
    """The periodic steady state's tolerance and warm-up budget for a data set.

    Parameters
    ----------
    dataset : Dataset
        Its sidecar may declare ``steady_state_tol_m`` and ``max_warmup_periods``.
    steady_state_tol_m, max_warmup_periods : optional
        Settings that win over the sidecar's (the command line's).

    Returns
    -------
    tuple
        ``(steady_state_tol_m, max_warmup_periods)``; :data:`STEADY_STATE_TOL_M` and
        :data:`MAX_WARMUP_PERIODS` where neither gives one.

    Raises
    ------
    SimulationError
        For a value that is not a positive number (a whole number >= 3 for the
        budget), naming the file.
    """
    meta = dataset.metadata or {}
    tol = meta.get("steady_state_tol_m", STEADY_STATE_TOL_M) if steady_state_tol_m is None \
        else steady_state_tol_m
    budget = meta.get("max_warmup_periods", MAX_WARMUP_PERIODS) if max_warmup_periods is None \
        else max_warmup_periods
    where = dataset.source or "the data set"
    if isinstance(tol, bool) or not isinstance(tol, int | float) or not tol > 0:
        raise SimulationError(f"{where}: steady_state_tol_m is {tol!r}; it must be a positive "
                              "number of metres (e.g. 1e-9)")
    if isinstance(budget, bool) or not isinstance(budget, int | np.integer) or budget < 3:
        raise SimulationError(f"{where}: max_warmup_periods is {budget!r}; it must be a whole "
                              "number of periods, at least 3 (e.g. 256)")
    return float(tol), int(budget)


def position_reference(dataset) -> str:
    """The data set's ``position_reference`` (:data:`POSITION_REFERENCES`), checked.

    Parameters
    ----------
    dataset : Dataset

    Returns
    -------
    str

    Raises
    ------
    SimulationError
        For another value, naming the file and the fix.
    """
    ref = (dataset.metadata or {}).get("position_reference", "absolute")
    if ref not in POSITION_REFERENCES:
        raise SimulationError(
            f"{dataset.source or 'the data set'}: metadata 'position_reference' is {ref!r}; it "
            f"must be one of {', '.join(map(repr, POSITION_REFERENCES))} ('start' where the "
            "sensor was zeroed with the actuator at rest at the record's start)")
    return ref


def simulate_dataset(model: Model, params, dataset, *, substeps: int = 1,
                     states: bool = False, steady_state_tol_m: float | None = None,
                     max_warmup_periods: int | None = None, per_trial: bool = False,
                     initial_values=None):
    """Simulate ``model`` on a data set's input, as the data set declares it.

    The one place where a data set's declarations become simulator options: what
    its input does between samples (:attr:`pmabayes.data.Dataset.input_between_samples`),
    its period (:attr:`~pmabayes.data.Dataset.period_samples`), whether each trial
    starts in periodic steady state
    (:attr:`~pmabayes.data.Dataset.starts_in_steady_state`, with the sidecar's
    ``steady_state_tol_m`` and ``max_warmup_periods``), from which state
    (:attr:`~pmabayes.data.Dataset.initial_state`) and to what its positions are
    referred (``position_reference``, :data:`POSITION_REFERENCES`). The likelihood,
    diagnostics and validation all simulate through it.

    Parameters
    ----------
    model : Model
        The composed model (on the data set's rig).
    params : mapping or array, optional
        Parameters, as accepted by :meth:`Model.theta`.
    dataset : Dataset
        The data: its first trial's input and its time grid are used (repeated
        trials share the input), or with ``per_trial`` every trial's own input.
    substeps : int
        Integration steps per sample interval.
    states : bool
        Return a :class:`Simulation` instead of positions.
    steady_state_tol_m, max_warmup_periods : optional
        The steady state's settings, over the sidecar's (:func:`warmup_settings`).
    per_trial : bool
        Simulate each trial on its own input (trials with measured inputs): ``R``
        trials and ``B`` parameter sets make ``R * B`` simulations, trial-major
        (member ``r * B + b``).
    initial_values : array_like, optional
        For a data set whose start is estimated (``initial_state == "estimate"``):
        ``(B, 3)`` starts, as :func:`simulate` takes them (shared by the trials).

    Returns
    -------
    numpy.ndarray or Simulation
        As :func:`simulate`, with ``per_trial`` positions ``(B, R, n_samples)`` (a
        :class:`Simulation`'s members stay trial-major); with ``position_reference``
        ``"start"`` the measured positions are relative to the model's at the first
        sample.
    """
    if not (isinstance(substeps, int | np.integer) and substeps >= 1):
        raise SimulationError(f"substeps must be an integer >= 1, got {substeps!r}")
    steady = dataset.starts_in_steady_state
    tol, budget = (warmup_settings(dataset, steady_state_tol_m, max_warmup_periods) if steady
                   else (STEADY_STATE_TOL_M, MAX_WARMUP_PERIODS))
    relative = position_reference(dataset) == "start"
    theta = model.theta(params)
    batch = theta.shape[0]
    init = _initial_values(dataset.initial_state, initial_values, batch, steady)
    u = dataset.input[0]
    if per_trial:
        trials = dataset.n_trials
        theta = np.tile(theta, (trials, 1))
        u = np.repeat(dataset.input, batch, axis=0)
        init = None if init is None else np.tile(init, (1, trials))
    out = _simulate_on_grid(model, theta, u, dataset.time_s,
                            dataset.grid_dt_s, substeps=int(substeps), states=states,
                            between_samples=dataset.input_between_samples,
                            period=(None if dataset.period_samples is None
                                    else int(dataset.period_samples)),
                            steady_state=steady, steady_state_tol_m=tol,
                            max_warmup_periods=budget, initial_state=dataset.initial_state,
                            init=init)
    if relative:
        out = (dataclasses.replace(out, position_m=out.position_m - out.position_m[:, :1])
               if states else out - out[:, :1])
    if not per_trial or states:
        return out
    return out.reshape(trials, batch, -1).transpose(1, 0, 2)
