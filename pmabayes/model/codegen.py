"""Source text of the compiled kernels: one composed model's physics as generated lines.

:class:`PlantCode` writes a model's plant (the linear part discretised exactly, the force
effects, the Bouc-Wen law of :mod:`pmabayes.model.boucwen` and its hysteresis effect)
as lines of Python for numba; :func:`generate` assembles the open-loop simulator's
kernel from them, and :mod:`pmabayes.control` its closed loop, so the two integrate
the plant identically. :func:`module_text` writes the module around a kernel's body;
:mod:`pmabayes.model.kernels` compiles and caches it. The documentation's page "The
simulator" (``docs/theory/simulator.rst``) gives the scheme.

The interface for kernels generated elsewhere (:mod:`pmabayes.control`) is
:class:`PlantCode` and :func:`module_text`; the emitted code's names are described on
:class:`PlantCode`.
"""

from __future__ import annotations

import numba

from pmabayes.data import INITIAL_STATES
from pmabayes.model import boucwen
from pmabayes.model.boucwen import BoucWenColumns
from pmabayes.model.model import Model

__all__ = ["FASTMATH", "LLVM_OPTIONS", "SimulationError", "PlantCode", "state_rows",
           "state_effects", "indent_lines", "module_text", "generate"]

#: numba fastmath flags of every generated kernel. ``contract`` (fused multiply-add)
#: and ``afn`` (approximate functions) let results differ in the last bits between
#: CPUs and numba/LLVM versions, never between runs on one machine and install.
FASTMATH = {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}

#: LLVM options every kernel is compiled under (set by :mod:`pmabayes.model.kernels`
#: when imported). LLVM's loop vectoriser gives up on a loop that needs more run-time
#: checks that its arrays do not overlap than its defaults allow; the member loop of a
#: kernel with many state rows (the degrading, pinching law's) needs more, and ran
#: scalar, five times slower (``analyses/law_kernel_speed.py``).
LLVM_OPTIONS = ("--runtime-memory-check-threshold=200",
                "--vectorize-memory-check-threshold=800")

#: Rows of ``cst`` (:class:`PlantCode`): 8 discretisation coefficients, then these.
_ALPHA_ROW, _BETA_ROW, _GAMMA_ROW, _DEAD_ZONE_ROW, _AREA_ROW, _GRAVITY_ROW = range(8, 14)


class SimulationError(ValueError):
    """Inputs to the simulator are inconsistent."""


def module_text(comments: list[str], inject: dict, name: str, args: str,
                body: list[str]) -> str:
    """The source of a generated kernel's module: its comments, the imports, the
    injected globals and the compiled function ``name(args)`` with ``body``.

    Parameters
    ----------
    comments : list of str
        Lines of the header (without ``#``): what generated it and for what.
    inject : dict
        Names of the globals set before the first call (:class:`PlantCode`'s
        ``inject`` and any of the caller's own).
    name, args : str
        The function's name and argument list.
    body : list of str
        Its lines, unindented.

    Returns
    -------
    str
    """
    text = "".join(f"# {c}\n" for c in comments)
    text += "import math\nimport numpy as np\nfrom numba import njit\n"
    # the one compiled helper the plant's setup calls
    text += "from pmabayes.model.kernels import discretise as _discretise\n"
    text += f"FASTMATH = set({sorted(FASTMATH)!r})\n"
    text += f"# compiled under the LLVM options {' '.join(LLVM_OPTIONS)}\n"
    for g in inject:
        text += f"{g} = None  # injected before the first call\n"
    # nogil: the simulator runs a large batch's members in threads, side by side
    # (:func:`pmabayes.model.simulator.simulation_threads`)
    text += "\n\n@njit(cache=True, fastmath=FASTMATH, error_model='numpy', nogil=True)\n"
    text += f"def {name}({args}):\n"
    text += indent_lines(body, 4) + "\n"
    return text


def indent_lines(lines: list[str], n: int) -> str:
    """Join generated ``lines`` indented by ``n`` spaces (blank lines stay empty).

    Parameters
    ----------
    lines : list of str
        Generated lines.
    n : int
        Spaces of indentation.

    Returns
    -------
    str
    """
    return "\n".join(" " * n + ln if ln else "" for ln in lines)


def _inlined(dispatcher):
    """An effect's function compiled to be inlined at numba's IR level."""
    fn = getattr(dispatcher, "py_func", dispatcher)
    return numba.njit(inline="always", error_model="numpy")(fn)


def state_rows(model: Model) -> int:
    """Rows of a kernel's state: ``x``, ``v``, ``z``, one per force effect with a state,
    and the hysteresis effect's last factor ``g`` (with a state: its last factor of
    ``alpha`` and its state too) (:class:`PlantCode`).

    Parameters
    ----------
    model : Model
        The composed model.

    Returns
    -------
    int
    """
    law = [e for e in model.effects if e.stage == "hysteresis"]
    return (3 + sum(1 for e in model.effects if e.stage == "force" and e.state is not None)
            + (1 if law else 0) + (2 if law and law[0].state is not None else 0))


def state_effects(model: Model) -> tuple:
    """The effects whose states a kernel holds, in the order a given start's extra
    columns carry them (``initial_values`` after position, velocity and ``z``): each
    force effect with a state, then a hysteresis law with one.

    Parameters
    ----------
    model : Model
        As :func:`state_rows`'s.

    Returns
    -------
    tuple of Effect classes
    """
    force = [e for e, _ in model.effect_slices() if e.stage == "force" and e.state is not None]
    law = [e for e, _ in model.effect_slices() if e.stage == "hysteresis" and e.state]
    return tuple(force + law[:1])


class PlantCode:
    """Generated source lines of one model's physics, for kernels built from them.

    The open-loop kernel (:func:`generate`) and the closed loop in
    :mod:`pmabayes.control` are generated from these same lines, so the two integrate
    the plant identically. Names in the emitted code: ``theta`` (the ``(batch,
    n_parameters)`` array) and ``cst`` (per-member constants, rows: 8 discretisation
    coefficients, alpha, beta, gamma, p_dz, and with rig values identified as
    parameters the area and the gravity force) can be renamed so that two models
    share one kernel; ``i`` is
    the batch member; ``mass``, ``f_grav``, ``area``, ``dt`` and ``substeps`` are
    kernel arguments. The state lives in rows of ``st``: ``x``, ``v``, ``z``, then
    one row per force effect with a state, then, with a hysteresis effect, its
    factor ``g`` over the last step, and for a law with a state its factor of
    ``alpha`` over the last step and the state (:attr:`n_rows` in all); :meth:`step`
    reads and writes these rows itself.

    Parameters
    ----------
    model : Model
        The composed model.
    theta, cst : str
        Names of the parameter array and of the constants in the emitted code.
    prefix : str
        Prefix of the names of the effects' injected functions.
    """

    def __init__(self, model: Model, *, theta: str = "theta", cst: str = "cst",
                 prefix: str = "_eff") -> None:
        self.model = model
        self.theta = theta
        self.cst = cst
        #: the base model's columns of ``theta``
        self.columns = BoucWenColumns.of(model)
        #: the Bouc-Wen law's constants in the emitted code (rows of ``cst``)
        self.alpha, self.beta, self.gamma = (f"{cst}[{r}, i]" for r in
                                             (_ALPHA_ROW, _BETA_ROW, _GAMMA_ROW))
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

    def col(self, name: str) -> str:
        """Expression of base parameter ``name`` (a field of :class:`BoucWenColumns`:
        ``"alpha"``, ``"d"``, ``"k_e"``, ...) of member ``i``."""
        return f"{self.theta}[i, {getattr(self.columns, name)}]"

    def setup(self) -> list[str]:
        """Lines filling ``cst`` and the force effects' parameter rows."""
        t, c = self.theta, self.cst
        rig = self.rig_cols
        mass = f"{t}[i, {rig['moving_mass_kg']}]" if "moving_mass_kg" in rig else "mass"
        alpha = self.col("alpha")
        lines = [
            f"{c} = np.empty(({_GRAVITY_ROW + 1 if rig else _AREA_ROW}, {t}.shape[0]))",
            "col = np.empty(8)",
            f"for i in range({t}.shape[0]):",
            # alpha (the hysteresis' initial stiffness) joins the exact linear part; only
            # the remainder r = z - alpha x is taken as linear in time over a step
            f"    _discretise({mass}, {self.col('d')}, {self.col('k_e')} + {alpha}, "
            "dt / substeps, col)",
            f"    {c}[:8, i] = col",
            f"    {self.alpha} = {alpha}",
            f"    {self.beta} = {self.col('beta')}",
            f"    {self.gamma} = {self.col('gamma')}",
            f"    {self.dead_zone_pa} = {self.col('p_dz') if self.dead_zone else '0.0'}",
        ]
        if rig:  # the kernel's mass, f_grav and area are the rig's nominal values
            area = f"{t}[i, {rig['area_m2']}]" if "area_m2" in rig else "area"
            lines += [f"    {c}[{_AREA_ROW}, i] = {area}",
                      f"    {c}[{_GRAVITY_ROW}, i] = f_grav * ({mass} / mass)"]
        # contiguous per-effect parameter rows: a strided slice defeats vectorisation
        lines += [f"{self.q(e)} = {t}[:, {s.start}:{s.stop}].copy()"
                  for e, s in self.force + self.law]
        return lines

    @property
    def dead_zone_pa(self) -> str:
        """Expression of member ``i``'s dead zone (0 on a force-driven rig)."""
        return f"{self.cst}[{_DEAD_ZONE_ROW}, i]"

    def actuator(self, p: str) -> str:
        """Expression of the actuator force minus gravity at pressure ``p``."""
        area, f_grav = ((f"{self.cst}[{_AREA_ROW}, i]", f"{self.cst}[{_GRAVITY_ROW}, i]")
                        if self.rig_cols else ("area", "f_grav"))
        if self.dead_zone:
            return f"{area} * max({p} - {self.dead_zone_pa}, 0.0) - {f_grav}"
        return f"{area} * {p} - {f_grav}"

    def balance(self, p: str, x: str, v: str, out: str, states: dict | None = None
                ) -> list[str]:
        """Lines setting ``out`` to the hysteretic force ``z`` that balances the actuator,
        the spring, the damper and the force effects (at ``z = 0``, their states at
        ``states``, 0 by default) at position ``x``, velocity ``v`` and pressure ``p``:
        the ``z`` of zero acceleration."""
        return [*self.forces(x, v, p, "fb", False, "0.0", states),
                f"{out} = {self.actuator(p)} - {self.col('k_e')} * {x} - {self.col('d')} * {v}"
                " - fb"]

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

    def advance_lines(self, e, state: str, x0: str, x1: str, h: str, out: str) -> list[str]:
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
        alpha = self.alpha
        if not self.law:
            return boucwen.rate_code(z, dx, alpha, self.beta, self.gamma)
        e = self.law[0][0]
        sign = [boucwen.coefficient_code(z, dx, self.beta, self.gamma)]
        if e.state is None:
            return sign + [
                f"zm = 0.5 * (abs({z}) + abs({z} + ({boucwen.slope_code(z, alpha, g_last)}) * "
                f"{dx}))",
                f"gm = {self.name_of[e]}({self.q(e)}[i], zm)",
                "c *= gm",
                f"kz = {boucwen.slope_code(z, alpha)}",
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
            f"zm = {z} + 0.5 * ({boucwen.slope_code(z, alpha + ' * ga', g_last)}) * {dx}",
            f"em = {self.name_of[e]}_adv({self.q(e)}[i], {state}, {z}, zm, 0.5 * {dx})",
            f"rg = {self.name_of[e]}({self.q(e)}[i], zm, {dx}, em)",
            "ga = rg[0]",
            "gm = rg[1]",
            "c *= gm",
            f"kz = {boucwen.slope_code(z, alpha + ' * ga')}",
        ]

    def update_lines(self, z: str, dx: str, out: str) -> list[str]:
        """Lines setting ``out`` to ``z`` after displacement ``dx`` (after :meth:`rate_lines`)."""
        law = (self.alpha, self.beta, self.gamma)
        if not self.law:
            return boucwen.update_code(z, dx, out, *law)
        return boucwen.update_code(z, dx, out, *law, scale="gm",
                                   alpha_scale="ga" if self.law_state else None)

    def rest(self, p: str, out: str) -> list[str]:
        """Lines setting ``out`` to the static equilibrium with ``z = 0`` at pressure ``p``."""
        k_e = self.col("k_e")
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
            step += self.advance_lines(e, start[e], x0, x0, "dt / substeps", pred[e])
        step += [
            f"r0 = {z0} - {self.alpha} * {x0}",
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
                f"ax = kz - {self.alpha} + efs_x" + (" + efs_z * kz" if self.reads_z else ""),
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
            step += [f"dx = dxs / (1.0 + {c}[6, i] * (kz - {self.alpha}))"]
            step += self.update_lines(z0, "dx", z1)
            step += [f"s = {z1} - {z0} - {self.alpha} * dx"]
        step += [f"{x1} = {x0} + dx", f"{v1} = vs - {c}[7, i] * s"]
        for e, row in self.state_row.items():
            step += self.advance_lines(e, start[e], x0, f"{x0} + dx", "dt / substeps", f"sv{row}")
            step += [f"st[{row}, i] = sv{row}"]
        if self.law:
            step += [f"{g_last} = gm"]
        if self.law_state:  # the state over the step, z having run from z0 to z1
            e = self.law[0][0]
            step += [f"{law_rows[0]} = ga",
                     f"{law_rows[1]} = {self.name_of[e]}_adv({self.q(e)}[i], {law_rows[1]}, "
                     f"{z0}, {z1}, dx)"]
        return step


def _check_initial_state(initial_state: str) -> None:
    """Refuse a start that is not one of :data:`~pmabayes.data.INITIAL_STATES`
    (:class:`SimulationError`)."""
    if initial_state not in INITIAL_STATES:
        raise SimulationError(
            f"initial_state must be one of {', '.join(map(repr, INITIAL_STATES))}, got "
            f"{initial_state!r}")


def generate(model: Model, record: bool, shared_input: bool,
             between_samples: str = "hold", initial_state: str = "rest",
             resume: bool = False) -> tuple[str, dict]:
    """Source of the open-loop kernel for ``model`` and the globals it needs injected.

    Parameters
    ----------
    model : Model
        The composed model.
    record, shared_input : bool
        Whether the kernel records every state, and whether one input drives the batch.
    between_samples : str
        The input between samples (:data:`~pmabayes.data.BETWEEN_SAMPLES`).
    initial_state : str
        The start (:data:`~pmabayes.data.INITIAL_STATES`).
    resume : bool
        Whether the kernel resumes from given state rows.

    Returns
    -------
    tuple
        ``(source, inject)``: the module's text (function ``kernel``) and the names of
        its globals with what to set them to; :func:`pmabayes.model.kernels.kernel_for`
        documents the kernel's arguments.
    """
    _check_initial_state(initial_state)
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

    comments = [
        "Generated by pmabayes.model.codegen for effects: "
        f"{', '.join(model.effect_names) or 'none'}. Do not edit.",
        f"input shared by the batch: {shared_input}; recording states: {record}",
        f"input between samples: {between_samples}",
    ]
    if zero or given:
        comments.append(f"initial state: {initial_state}")
    if resume:
        comments.append("resumes from a given state")
    text = module_text(comments, plant.inject, "kernel", args, body)
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
        # the effects' states after x, v and z (state_effects): given, not at rest
        given_rows = {e: plant.state_row.get(e, (plant.law_row or 0) + 2)
                      for e in state_effects(plant.model)}
        out += [f"    st[{row}, i] = init[{3 + j}, i]"
                for j, row in enumerate(given_rows.values())]
        out += ["    " + ln for ln in plant.balance("p0", "xi", "init[1, i]", "zi",
                                                    {e: f"st[{r}, i]" for e, r in
                                                     plant.state_row.items()})]
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

