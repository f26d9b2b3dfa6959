"""Batched, compiled simulation of a composed :class:`~pmabayes.model.model.Model`.

Integration scheme
------------------
The muscle is stiff: with the paper's masses the linear part has poles near -4 and
-2300 rad/s, so explicit Euler diverges at 1 kHz. Each sample interval is
integrated as follows.

* The linear mass-spring-damper is discretised *exactly* (matrix exponential)
  for a force that varies linearly over the interval (first-order hold). This
  part is unconditionally stable at any step.
* The force is the actuator force ``A max(p - p_dz, 0)`` minus gravity, the
  hysteretic force ``z`` and any effect forces. Its values at the interval's
  start and end are used; the end values depend on the unknown end state, which
  is found by a Newton iteration on one scalar (the force increment), using the
  derivatives ``dz/dx`` and each force effect's ``df/dx``, ``df/dv``.
* ``z`` is advanced by the exact solution of ``dz/dx = alpha - c|z|`` for the
  step's displacement (``c`` fixed by the signs of ``dx`` and ``z``), so the
  hysteresis is integrated without a step-size limit of its own. A hysteresis
  effect's factor ``g(|z|)`` (``dz/dx = alpha - c|z| g``) is frozen at the step's
  mean ``|z|``.
* Force effects may read ``z`` (their ``z`` derivative joins the implicit step
  through ``dz/dx``) and carry a state, advanced exactly over the step with ``x``
  linear in time; its slope in the end position joins the implicit step too.

The scheme is second order. Against a Radau solution at rtol 1e-10 the error over
the 15 s chirp of the paper is about 3e-7 m at 1 kHz (see ``tests/test_simulator.py``).

Conventions
-----------
By default ``input[k]`` (pressure in Pa, or force in N) is held from ``time_s[k]``
to ``time_s[k+1]``; ``between_samples`` chooses a straight line between samples, or
a band-limited reconstruction (FFT interpolation of a periodic record, else a
degree-9 interpolating spline) that each substep follows as a straight line between
its reconstructed end values. ``position_m[k]`` is the position at ``time_s[k]``.
Each trial starts at rest: ``x' = 0``, ``z = 0`` and ``x`` at static equilibrium
under the first input sample; or, with ``initial_state="zero"``, at ``x = x' = z = 0``
whatever the first input (a simulation switched on at t = 0, as the Bouc-Wen
benchmark's); or, with ``initial_state="estimate"``, from a state given per batch member
(``initial_values``: position, velocity, and ``z`` as an offset from the balance of
forces at that position and velocity); or, with ``steady_state``, in the periodic
steady state reached from that initial state through repeated periods of the input.

Kernels are generated per composition of effects, compiled with numba and cached
on disk (``$PMABAYES_CACHE_DIR``, default ``~/.cache/pmabayes``), so the first
call of a new composition compiles for a few seconds and later processes load it.
"""

from __future__ import annotations

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
from pmabayes.util import fingerprint, source_text

__all__ = ["simulate", "simulate_dataset", "Simulation", "kernel_for", "cache_dir",
           "SimulationError", "SteadyStateWarning", "BETWEEN_SAMPLES", "INITIAL_STATES",
           "STEADY_STATE_TOL_M", "MAX_WARMUP_PERIODS"]

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
    while norm > 0.25:
        norm *= 0.5
        squarings += 1
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
                    scale: str | None = None) -> list[str]:
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
    scaled too (``c`` and ``kz`` must already be).
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
    lines += [f"{out} = rem * {cst}[8, i] * ph2 if cross else z_nc"]
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
    factor ``g`` over the last step (:attr:`n_rows` in all); :meth:`step` reads and
    writes these rows itself.
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
        self.inject.update({f"{self.name_of[e]}_adv": _inlined(e.advance) for e in stateful})
        #: row of ``st`` holding each stateful force effect's state
        self.state_row = {e: 3 + j for j, e in enumerate(stateful)}
        self.reads_z = any(e.reads_z for e, _ in self.force)
        #: row of ``st`` holding the hysteresis effect's last factor ``g``
        self.law_row = 3 + len(self.state_row) if self.law else None

    @property
    def n_rows(self) -> int:
        """Rows of the state array ``st``: ``x``, ``v``, ``z``, the effects' states, ``g``."""
        return 3 + len(self.state_row) + (1 if self.law else 0)

    def q(self, e) -> str:
        """Name of the contiguous parameter rows of force effect ``e``."""
        return f"q{self.name_of[e]}"

    def setup(self) -> list[str]:
        """Lines filling ``cst`` and the force effects' parameter rows."""
        t, c = self.theta, self.cst
        lines = [
            f"{c} = np.empty((12, {t}.shape[0]))",
            "col = np.empty(8)",
            f"for i in range({t}.shape[0]):",
            # alpha (the hysteresis' initial stiffness) joins the exact linear part; only
            # the remainder r = z - alpha x is taken as linear in time over a step
            f"    _discretise(mass, {t}[i, 3], {t}[i, 4] + {t}[i, 0], dt / substeps, col)",
            f"    {c}[:8, i] = col",
            f"    {c}[8, i] = {t}[i, 0]",
            f"    {c}[9, i] = {t}[i, 1]",
            f"    {c}[10, i] = {t}[i, 2]",
            f"    {c}[11, i] = {t + '[i, 5]' if self.dead_zone else '0.0'}",
        ]
        # contiguous per-effect parameter rows: a strided slice defeats vectorisation
        lines += [f"{self.q(e)} = {t}[:, {s.start}:{s.stop}].copy()"
                  for e, s in self.force + self.law]
        return lines

    def actuator(self, p: str) -> str:
        """Expression of the actuator force minus gravity at pressure ``p``."""
        if self.dead_zone:
            return f"area * max({p} - {self.cst}[11, i], 0.0) - f_grav"
        return f"area * {p} - f_grav"

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

    def rate_lines(self, z: str, dx: str, g_last: str = "0.0") -> list[str]:
        """Lines setting ``c`` and ``kz = dz/dx`` at ``z`` for motion in the direction of ``dx``.

        With a hysteresis effect its factor ``g`` is evaluated once, at the step's mean
        ``|z|`` (the ends predicted with ``g_last``, the factor of the step before, an
        expression), and frozen over the step: ``c`` holds ``c g`` and ``gm`` holds
        ``g`` (store it for the next step's ``g_last``), for :meth:`update_lines`, whose
        Bouc-Wen step is then exact for that ``g``: second order in all.
        """
        if not self.law:
            return bw_rate_lines(z, dx, self.cst)
        e, c = self.law[0][0], self.cst
        return [
            f"c = {c}[9, i] * (1.0 if {dx} * {z} >= 0.0 else -1.0) + {c}[10, i]",
            f"zm = 0.5 * (abs({z}) + abs({z} + ({c}[8, i] - c * {g_last} * abs({z})) * {dx}))",
            f"gm = {self.name_of[e]}({self.q(e)}[i], zm)",
            "c *= gm",
            f"kz = {c}[8, i] - c * abs({z})",
        ]

    def update_lines(self, z: str, dx: str, out: str) -> list[str]:
        """Lines setting ``out`` to ``z`` after displacement ``dx`` (after :meth:`rate_lines`)."""
        if not self.law:
            return bw_update_lines(z, dx, out, self.cst)
        return bw_update_lines(z, dx, out, self.cst, scale="gm")

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

    def balance(self, p: str, x: str, v: str, out: str) -> list[str]:
        """Lines setting ``out`` to the hysteretic force ``z`` that balances the actuator,
        the spring, the damper and the force effects (at ``z = 0``) at position ``x``,
        velocity ``v`` and pressure ``p``: the ``z`` of zero acceleration."""
        t = self.theta
        return [*self.forces(x, v, p, "fb", False),
                f"{out} = {self.actuator(p)} - {t}[i, 4] * {x} - {t}[i, 3] * {v} - fb"]

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
        step += self.rate_lines(z0, "dxs", g_last)
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
        return step


def _generate(model: Model, record: bool, shared_input: bool,
              between_samples: str = "hold", initial_state: str = "rest") -> tuple[str, dict]:
    """Source of the kernel for ``model`` and the globals it needs injected."""
    plant = PlantCode(model)
    zero = initial_state == "zero"
    pressure, measure = plant.pressure, plant.measure
    name_of = plant.name_of

    # a given start (``init``: (3, batch)) is an argument only where it is used
    given = initial_state == "estimate"
    args = ("theta, p_in, time_s, dt, substeps, mass, f_grav, area, "
            + ("init, " if given else "") + "out_x")
    if record:
        args += ", out_v, out_z, out_p, out_f, out_true"
    # Few distinct arrays keep the vectoriser's runtime alias checks cheap: all
    # per-member constants live in rows of `cst`, the state in rows of `st`.
    body = ["n = out_x.shape[0]", "batch = theta.shape[0]"] + plant.setup()
    # within a sample interval the pressure is linear from pp[0] to pp[1]
    linear = between_samples == "linear"
    body += [f"st = np.zeros(({plant.n_rows}, batch))"]
    if between_samples == "bandlimited":
        # p_in holds the reconstructed input at every substep boundary (fine index
        # k * substeps + j); each substep takes the straight line between two of them
        fine = "k * substeps + j"
        if shared_input and not pressure:
            body += _sample_loops(plant, record, "pa", "pb", "p_in[(k + 1) * substeps, 0]",
                                  "p_in[0, 0]",
                                  substep_lines=[f"pa = p_in[{fine}, 0]",
                                                 f"pb = p_in[{fine} + 1, 0]"], zero=zero,
                                  given=given)
        else:
            body += (_pressure_fill(plant, shared_input, True, fine=True)
                     + _sample_loops(plant, record, f"pp[0, {fine}, i]", f"pp[1, {fine}, i]",
                                     "pp[0, (k + 1) * substeps, i]", "pp[0, 0, i]", zero=zero,
                                     given=given))
    else:
        ramps = bool(pressure) or linear
        via_pp = (
            "(pp[0, k, i] + (pp[1, k, i] - pp[0, k, i]) * fa)" if ramps else "pp[0, k, i]",
            "(pp[0, k, i] + (pp[1, k, i] - pp[0, k, i]) * fb)" if ramps else "pp[0, k, i]",
            "pp[0, k + 1, i]",
            "pp[0, 0, i]",
        )
        shared = ("pk", "pk", "p_in[k + 1, 0]", "p_in[0, 0]")
        # one loop per kernel: a second copy in the same function does not vectorise
        if ramps or not shared_input:
            body += (_pressure_fill(plant, shared_input, linear)
                     + _sample_loops(plant, record, *via_pp, zero=zero, given=given))
        else:
            body += _sample_loops(plant, record, *shared, zero=zero, given=given)
    if record:
        body += ["out_true[:, :] = out_x"]
    body += [f"{name_of[e]}(theta[:, {s.start}:{s.stop}], time_s, out_x)" for e, s in measure]

    text = _HEADER.format(effects=", ".join(model.effect_names) or "none")
    text += f"# input shared by the batch: {shared_input}; recording states: {record}\n"
    text += f"# input between samples: {between_samples}\n"
    if zero or given:  # only then, so that the rest kernels' text (and disk cache) is unchanged
        text += f"# initial state: {initial_state}\n"
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
                  zero: bool = False, given: bool = False) -> list[str]:
    """Lines of the initial state and the time loop, given how the pressure at the
    start and end of a substep, at the next sample and at the first is read
    (``substep_lines`` run once per substep, before the batch loop). The state starts
    at rest under the first input, with ``zero`` at ``x = x' = z = 0``, or with
    ``given`` at ``init[:, i]``: position, velocity, and ``z`` as an offset from the
    balance at that position and velocity (:meth:`PlantCode.balance`)."""
    out = ["for i in range(batch):", f"    p0 = {p_first}"]
    if given:
        out += ["    xi = init[0, i]", "    st[1, i] = init[1, i]"]
        out += ["    " + ln for ln in plant.balance("p0", "xi", "init[1, i]", "zi")]
        out += ["    st[2, i] = zi + init[2, i]"]
    else:
        out += ["    xi = 0.0"] if zero else ["    " + ln for ln in plant.rest("p0", "xi")]
    out += ["    st[0, i] = xi", "    out_x[0, i] = xi"]
    if record:
        v, z = ("st[1, i]", "st[2, i]") if given else ("0.0", "0.0")
        out += [f"    out_v[0, i] = {v}", f"    out_z[0, i] = {z}", "    out_p[0, i] = p0"]
        out += ["    " + ln for ln in plant.forces("xi", v, "p0", "f0", False, z)]
        out += ["    out_f[0, i] = f0"]
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
    out += ["for k in range(n - 1):"]
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
                  between_samples: str = "hold", initial_state: str = "rest") -> tuple:
    """Key of a kernel's composition: the effects (by identity), the input kind and
    the conventions of the input between samples and of the initial state."""
    key = (
        tuple((e.__module__, e.__qualname__, id(e)) for e in model.effects),
        model.rig.input_kind,
        record,
        shared_input,
    )
    key = key if between_samples == "hold" else (*key, between_samples)
    return key if initial_state == "rest" else (*key, "initial_state", initial_state)


def kernel_for(model: Model, *, record: bool = False, shared_input: bool = True,
               between_samples: str = "hold", initial_state: str = "rest"):
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

    Returns
    -------
    numba dispatcher
        ``kernel(theta, p_in, time_s, dt, mass, f_grav, area, out_x[, ...])``.
    """
    if initial_state not in INITIAL_STATES:
        raise SimulationError(
            f"initial_state must be one of {', '.join(map(repr, INITIAL_STATES))}, got "
            f"{initial_state!r}")
    key = structure_key(model, record, shared_input, between_samples, initial_state)
    kernel = cached_kernel(key)
    if kernel is not None:
        return kernel
    text, inject = _generate(model, record, shared_input, between_samples, initial_state)
    return compile_kernel(key, text, inject)


def cached_kernel(key: tuple):
    """The kernel compiled under ``key`` in this process, or None (check before generating)."""
    with _LOCK:
        return _KERNELS.get(key)


def compile_kernel(key: tuple, text: str, inject: dict, name: str = "kernel"):
    """Compile generated source (module-level function ``name``), cached on disk and in memory.

    Shared by every generated kernel (here and in :mod:`pmabayes.control`); the file
    name hashes the source, the helpers it calls and the library versions, so a
    change to any of them compiles afresh.
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


#: Default tolerance of the periodic steady state in m: the warm-up stops when the
#: record's estimated offset from the steady state (from the last two warm-up periods'
#: changes of position, extrapolated geometrically) is at most this.
STEADY_STATE_TOL_M = 1e-9
#: Default most periods simulated from rest before a record that starts in steady state.
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
    fine = _fine_input(u, substeps, period is not None)
    if warmup:
        one = (_fine_periodic(u[..., :period], substeps) if substeps > 1
               else u[..., :period])
        fine = np.concatenate([np.tile(one, warmup), fine], axis=-1)
    return fine


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
        The record starts in periodic steady state: the model is first driven from
        rest by the record's first period, repeated, and the record continues from
        the state so reached. False (default): the record starts from rest.
    steady_state_tol_m : float
        Tolerance of the steady state in m (default :data:`STEADY_STATE_TOL_M`):
        enough warm-up periods that the position's change over the last one, ``d``,
        and the record's estimated remaining offset ``d r / (1 - r)`` (``r`` the
        ratio of the last two changes: the transient's decay per period) are both
        at most this.
    max_warmup_periods : int
        Most warm-up periods (default :data:`MAX_WARMUP_PERIODS`). The first try
        has 3; the next as many as the decay ``r`` says are needed (or twice as
        many). If the tolerance is not reached, a :class:`SteadyStateWarning` says
        by how much, and the record follows the last warm-up. The muscle at the
        paper's values creeps towards its steady state by about ``r = 0.84`` a
        period (the hysteresis' slow shakedown), so it can take a hundred.
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
    init = _initial_values(initial_state, initial_values, theta.shape[0], steady_state)
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
    if v.shape != (batch, 3) or not np.all(np.isfinite(v)):
        raise SimulationError(f"initial_values must be 3 finite values, or ({batch}, 3) for "
                              f"a batch of {batch}; got shape {v.shape}")
    return np.ascontiguousarray(v.T)


def _simulate_on_grid(model: Model, theta: np.ndarray, u: np.ndarray, t: np.ndarray,
                      dt: float, *, substeps: int, states: bool, between_samples: str,
                      period: int | None, steady_state: bool, steady_state_tol_m: float,
                      max_warmup_periods: int, initial_state: str,
                      init: np.ndarray | None = None):
    """:func:`simulate` on a checked input and time grid (the data set's own, checked
    when it was made: the sampler calls this thousands of times)."""
    run = dict(model=model, theta=theta, u=u, t=t, dt=dt, substeps=substeps,
               states=states, between_samples=between_samples, period=period,
               initial_state=initial_state, init=init)
    if not steady_state:
        return _run(**run, warmup=0)
    tol = float(steady_state_tol_m)
    warmup = min(3, int(max_warmup_periods))
    while True:
        record, warm = _run(**run, warmup=warmup)
        x = warm.true_position_m if states else warm
        change, offset, ratio = _transient(x, period)
        if offset <= tol:
            return record
        if warmup >= max_warmup_periods or not np.isfinite(change):
            warnings.warn(
                f"simulate: no periodic steady state within {tol:g} m after {warmup} "
                f"warm-up periods of {period} samples: the last period still changed by "
                f"{change:.3g} m (by {ratio:.3g} times the change before). The record starts "
                "from that state; pass a larger max_warmup_periods or steady_state_tol_m.",
                SteadyStateWarning, stacklevel=2)
            return record
        if 0.0 < ratio < 1.0:  # geometric decay: periods until the offset is below tol
            target = tol * min(1.0, (1.0 - ratio) / ratio)
            more = int(np.ceil(np.log(target / change) / np.log(ratio))) + 1
            warmup = min(max(warmup + more, warmup + 1), 4 * warmup)
        else:
            warmup *= 2
        warmup = min(warmup, int(max_warmup_periods))


def _transient(x: np.ndarray, period: int) -> tuple[float, float, float]:
    """How far warm-up positions ``x`` (``(B, k * period)``, ``k >= 3``) are from
    periodic: the largest change over the last period, the record's estimated
    remaining offset (``change r / (1 - r)``, ``r`` the ratio of the last two changes;
    infinite if they do not shrink) and ``r``."""
    last = x[:, -period:] - x[:, -2 * period:-period]
    before = x[:, -2 * period:-period] - x[:, -3 * period:-2 * period]
    change = float(np.max(np.abs(last)))
    prior = float(np.max(np.abs(before)))
    ratio = change / prior if prior > 0.0 else 0.0
    if not np.isfinite(change):
        return change, np.inf, ratio
    if change <= 1e-15 * max(float(np.max(np.abs(x[:, -period:]))), 1e-300):
        return change, change, ratio  # changes at rounding level: periodic
    offset = change * ratio / (1.0 - ratio) if ratio < 1.0 else np.inf
    return change, max(change, offset), ratio


class SteadyStateWarning(RuntimeWarning):
    """The periodic steady state was not reached within the warm-up allowed."""


def _run(*, model: Model, theta: np.ndarray, u: np.ndarray, t: np.ndarray, dt: float,
         substeps: int, states: bool, between_samples: str, period: int | None,
         warmup: int, initial_state: str = "rest", init: np.ndarray | None = None):
    """One kernel call over ``warmup`` periods and the record.

    Returns the positions ``(B, n)`` (or the :class:`Simulation`) of the record; with
    a warm-up, ``(record, warm-up positions ((B, warmup * period)))``, the latter the
    true positions when ``states``.
    """
    n = u.shape[-1]
    p_in = _kernel_input(u, substeps, between_samples, period, warmup)
    shared = u.ndim == 1
    p_in = np.ascontiguousarray(p_in[:, None] if shared else p_in)
    lead = warmup * (period or 0)
    if lead:
        t = np.concatenate([t[0] + dt * np.arange(-lead, 0), t])
    rig = model.rig
    batch = theta.shape[0]
    out_x = np.empty((n + lead, batch))
    args = (theta, p_in, t, dt, substeps, rig.moving_mass_kg, rig.gravity_force_n,
            rig.area_m2, *(() if init is None else (init,)), out_x)
    if not states:
        kernel_for(model, shared_input=shared, between_samples=between_samples,
                   initial_state=initial_state)(*args)
        x = out_x.T
        return (x[:, lead:], x[:, :lead]) if lead else x
    rec = [np.empty((n + lead, batch)) for _ in range(5)]
    kernel_for(model, record=True, shared_input=shared, between_samples=between_samples,
               initial_state=initial_state)(*args, *rec)
    v, z, p, f, true_x = (a.T for a in rec)
    x = out_x.T
    sim = Simulation(t[lead:], x[:, lead:], true_x[:, lead:], v[:, lead:], z[:, lead:],
                     p[:, lead:], f[:, lead:])
    if not lead:
        return sim
    return sim, Simulation(t[:lead], x[:, :lead], true_x[:, :lead], v[:, :lead],
                           z[:, :lead], p[:, :lead], f[:, :lead])


def simulate_dataset(model: Model, params, dataset, *, substeps: int = 1,
                     states: bool = False, per_trial: bool = False,
                     initial_values=None):
    """Simulate ``model`` on a data set's input, as the data set declares it.

    The one place where a data set's declarations become simulator options: what
    its input does between samples (:attr:`pmabayes.data.Dataset.input_between_samples`),
    its period (:attr:`~pmabayes.data.Dataset.period_samples`), whether each trial
    starts in periodic steady state
    (:attr:`~pmabayes.data.Dataset.starts_in_steady_state`) and from which state
    (:attr:`~pmabayes.data.Dataset.initial_state`). The likelihood,
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
        As :func:`simulate`; with ``per_trial``, positions ``(B, R, n_samples)``
        (a :class:`Simulation`'s members stay trial-major).
    """
    if not (isinstance(substeps, int | np.integer) and substeps >= 1):
        raise SimulationError(f"substeps must be an integer >= 1, got {substeps!r}")
    theta = model.theta(params)
    batch = theta.shape[0]
    init = _initial_values(dataset.initial_state, initial_values, batch,
                           dataset.starts_in_steady_state)
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
                             steady_state=dataset.starts_in_steady_state,
                             steady_state_tol_m=STEADY_STATE_TOL_M,
                             max_warmup_periods=MAX_WARMUP_PERIODS,
                             initial_state=dataset.initial_state, init=init)
    if not per_trial or states:
        return out
    return out.reshape(trials, batch, -1).transpose(1, 0, 2)
