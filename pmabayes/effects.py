"""Composable physical effects.

An effect is one small class that keeps its parameters, priors, physics and
meaning together. It acts at one *stage* of the signal path:

``"pressure"``
    Transforms the pressure that reaches the actuator, before the dead zone
    (regulator lag, transport delay). The pressure over each sample interval is
    given by its values at the interval's start and end (the simulator
    interpolates linearly between them); the physics function rewrites both in
    place for a whole batch of parameter sets::

        physics(q, p_start, p_end, dt_s) -> None

    with ``q`` of shape ``(batch, n_params)`` and ``p_start``, ``p_end`` of shape
    ``(n_samples, batch)``. Loop over samples outside and the batch inside, so the
    loop vectorises.

``"force"``
    Adds a force that opposes extension, on the same side of the equation of
    motion as the stiffness ``K_e x`` (friction, nonlinear stiffness). The physics
    function is called for one parameter set at one instant and returns the force
    and its partial derivatives, which the implicit integrator needs::

        physics(q, x_m, v_m_s, p_pa) -> (force_n, dforce_dx, dforce_dv)

    with ``q`` of shape ``(n_params,)``.

``"measurement"``
    Maps the simulated position to what the sensor reports, in place, for the
    whole batch (``q`` as for pressure effects, ``position_m`` of shape
    ``(n_samples, batch)``)::

        physics(q, time_s, position_m) -> None

``"hysteresis"``
    Changes the law of the Bouc-Wen force ``z`` itself. The law stays
    ``dz/dx = alpha - (beta sgn(dx z) + gamma) |z| g(|z|)``; the physics function
    returns the factor ``g`` (1 for the paper's model) and is called for one
    parameter set at one instant (``q`` of shape ``(n_params,)``)::

        physics(q, z_abs_n) -> g

    The simulator integrates ``z`` over each step exactly with ``g`` frozen at its
    value at the step's mean ``|z|`` (second order, like the rest of the scheme).
    Keep ``g`` finite and of moderate size (``|c| g |dx|`` stays well below 1 over a
    step) and free of libm calls (``math.exp``, ``**``) if the batch loop is to
    vectorise: :func:`power` is a libm-free ``y**e``. A model holds at most
    one hysteresis effect.

**Force effects that read z or carry a state.** A force effect may set
``reads_z = True`` (its force depends on the hysteretic force ``z``) and/or
``state`` to the name of one internal state of its own (a dashpot's
displacement, say; every state starts at 0 with the muscle at rest). It then
takes the extended signature, returning the derivatives with respect to ``z``
and to its state too (0 when it has none)::

    physics(q, x_m, v_m_s, p_pa, z_n, state) -> (force_n, dforce_dx, dforce_dv,
                                                dforce_dz, dforce_dstate)

and an effect with a state also sets ``advance``, the state's exact change over
a step of length ``h_s`` during which the position runs in a straight line from
``x0_m`` to ``x1_m``, with the new state's derivative in ``x1_m`` (which the
linearly implicit step needs)::

    advance(q, state, x0_m, x1_m, h_s) -> (new_state, dnew_state_dx1)

Both are called for one parameter set at one instant and compiled like
``physics``. Force effects written to the four-argument signature keep working
unchanged.

Parameters arrive in ``q`` in the order the effect declares them. The physics
function is compiled with numba (a plain Python function is compiled when the
class is defined), so effects never fall back to a Python loop inside the
simulator.

**What the closed loop needs** (:mod:`pmabayes.control`). An effect may tell the
controller how to compensate it, through optional hooks whose defaults keep an
effect without them working (simulated in the loop, not compensated). The
classmethods take a batch of the effect's own parameter values, ``q`` of shape
``(batch, n_params)`` in declared order, and return one value per row:

``history_s(q)``
    Seconds of past pressure command a pressure effect needs to start each
    closed-loop update from (default: 2 s for a pressure effect, 0 otherwise).
``lead_s(q)``
    Seconds of lead the effect adds on the pressure path; computed torque
    predicts the reference and the position that far ahead (default 0).
``add_delay(q, delay_s)``
    The parameter rows with ``delay_s`` more dead time, for the gain rule's delay
    margin, or None when the effect cannot absorb a delay (the default). A model
    without such an effect gains :func:`delay_effect` for the margin.

A measurement effect may also set ``inverse``, the reading mapped back to the
position, for one parameter set at one instant, with the inverse's slope (which
maps the reading's increments, for the velocity estimate)::

    inverse(q, time_s, reading_m) -> (position_m, dposition_dreading)

with ``q`` of shape ``(n_params,)``; compiled like ``physics``. Computed torque
applies the inverses of its model's measurement effects to the reading, the last
effect's first; without ``inverse`` (None, the default) an effect is not inverted.

Writing a new effect takes a dozen lines; see :class:`Effect` for examples.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import ClassVar

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from pmabayes.parameters import HalfNormal, LogNormal, Normal, Parameter

__all__ = [
    "STAGES",
    "Effect",
    "EffectError",
    "smooth_sign",
    "register_effect",
    "registered_effects",
    "get_effect",
    "resolve_effects",
    "RegulatorLag",
    "TransportDelay",
    "CoulombFriction",
    "CubicStiffness",
    "PressureStiffness",
    "PositionOffset",
    "PressureHysteresis",
    "MaxwellCreep",
    "BoucWenExponent",
    "power",
    "decay",
    "StribeckFriction",
    "McKibbenForce",
    "RegulatorSecondOrder",
    "delay_effect",
]

STAGES = ("pressure", "force", "measurement", "hysteresis")


class EffectError(ValueError):
    """An effect is malformed, unknown, or clashes with another."""


class Effect:
    """Base class of a physical effect.

    Subclasses set four class attributes and one physics function (a measurement
    effect may add its inverse):

    Attributes
    ----------
    name : str
        Registry name, a Python identifier (``"regulator_lag"``).
    stage : str
        One of ``"pressure"``, ``"force"``, ``"measurement"``.
    parameters : tuple of Parameter
        The effect's parameters; names must not clash with any other parameter of
        the model it is added to.
    description : str
        One paragraph: the physics, and the signature it leaves in the residual.
    physics : callable
        The stage's function (see the module docstring), wrapped in
        ``staticmethod``. Plain Python functions are compiled with
        ``numba.njit`` when the class is defined.
    inverse : callable or None
        Optional, measurement effects only: the reading mapped back to the position
        and the slope of that map, ``inverse(q, time_s, reading_m) -> (position_m,
        dposition_dreading)``, which computed torque applies to its reading.
        Compiled like ``physics``.
    reads_z : bool
        Optional, force effects only: the force depends on the hysteretic force
        ``z``; ``physics`` then has the extended signature (module docstring).
    state : str or None
        Optional, force effects only: the name of the effect's one internal state
        (starting at 0 at rest); ``physics`` then has the extended signature and
        ``advance`` must be set.
    advance : callable or None
        With ``state``: the state's exact change over one step, ``advance(q, state,
        x0_m, x1_m, h_s) -> (new_state, dnew_state_dx1)``. Compiled like ``physics``.

    Notes
    -----
    Three optional classmethods tell the closed loop (:mod:`pmabayes.control`)
    how to compensate the effect: :meth:`history_s`, :meth:`lead_s` and
    :meth:`add_delay`. Each takes the effect's own parameter values for a batch,
    ``(batch, n_params)`` in declared order. Their defaults leave the effect
    uncompensated, and give a pressure effect 2 s of command history.

    Examples
    --------
    A quadratic (turbulent) drag, written outside the package:

    >>> import numpy as np
    >>> from pmabayes import Effect, Parameter, HalfNormal, Normal, register_effect
    >>> def drag(q, x, v, p):
    ...     c = q[0]
    ...     return c * v * abs(v), 0.0, 2.0 * c * abs(v)
    >>> class QuadraticDrag(Effect):
    ...     name = "quadratic_drag"
    ...     stage = "force"
    ...     parameters = (Parameter("c_quad", "N s^2/m^2", 50.0, HalfNormal(200.0),
    ...                             bounds=(0.0, 1e5), null=0.0,
    ...                             description="drag force per squared velocity"),)
    ...     description = "Drag growing with the square of velocity."
    ...     physics = staticmethod(drag)
    >>> _ = register_effect(QuadraticDrag)

    A first-order lag of the pressure, compensated by computed torque: it needs
    about ``40 tau`` of command history and adds a lead of ``tau``:

    >>> def lag(q, p_start, p_end, dt_s):
    ...     n, batch = p_start.shape
    ...     for i in range(batch):
    ...         y, w = p_start[0, i], 1.0 - np.exp(-dt_s / q[i, 0])
    ...         for k in range(n):
    ...             p_start[k, i] = y
    ...             y += w * (p_end[k, i] - y)
    ...             p_end[k, i] = y
    >>> class SlowValve(Effect):
    ...     name = "slow_valve"
    ...     stage = "pressure"
    ...     parameters = (Parameter("tau_valve", "s", 0.03, HalfNormal(0.1),
    ...                             bounds=(1e-6, 1.0)),)
    ...     description = "First-order lag of the valve."
    ...     physics = staticmethod(lag)
    ...     @classmethod
    ...     def history_s(cls, q):
    ...         return 40.0 * q[:, 0]
    ...     @classmethod
    ...     def lead_s(cls, q):
    ...         return q[:, 0]

    A sensor with a gain and an offset, inverted by computed torque:

    >>> def gain_offset(q, time_s, position_m):
    ...     for k in range(position_m.shape[0]):
    ...         for i in range(position_m.shape[1]):
    ...             position_m[k, i] = q[i, 0] * position_m[k, i] + q[i, 1]
    >>> def gain_offset_inverse(q, time_s, reading_m):
    ...     return (reading_m - q[1]) / q[0], 1.0 / q[0]
    >>> class ScaledSensor(Effect):
    ...     name = "scaled_sensor"
    ...     stage = "measurement"
    ...     parameters = (
    ...         Parameter("k_sensor", "1", 1.0, Normal(1.0, 0.1), bounds=(0.5, 2.0)),
    ...         Parameter("b_sensor", "m", 0.0, Normal(0.0, 1e-3), bounds=(-0.01, 0.01)))
    ...     description = "Sensor gain and offset."
    ...     physics = staticmethod(gain_offset)
    ...     inverse = staticmethod(gain_offset_inverse)

    A force that reads ``z`` and carries a state: a spring ``k`` in series with a
    dashpot of time constant ``tau``, whose stretch ``u`` relaxes as
    ``u' = x' - u / tau`` (exact over a step with ``x`` linear in time):

    >>> from pmabayes.effects import decay
    >>> def creep(q, x, v, p, z, u):
    ...     return q[0] * u, 0.0, 0.0, 0.0, q[0]
    >>> def creep_advance(q, u, x0, x1, h):
    ...     e, phi = decay(h / q[1])  # exp(-h/tau), (1 - exp(-h/tau)) / (h/tau)
    ...     return u * e + (x1 - x0) * phi, phi
    >>> class SlowCreep(Effect):
    ...     name = "slow_creep"
    ...     stage = "force"
    ...     state = "u_slow"
    ...     parameters = (
    ...         Parameter("k_slow", "N/m", 100.0, HalfNormal(500.0), bounds=(0.0, 1e5),
    ...                   null=0.0),
    ...         Parameter("tau_slow", "s", 2.0, HalfNormal(5.0), bounds=(1e-3, 100.0),
    ...                   vary=False))
    ...     description = "Spring and dashpot in series, beside the muscle."
    ...     physics = staticmethod(creep)
    ...     advance = staticmethod(creep_advance)

    A hysteresis effect returns the factor ``g(|z|)`` of the Bouc-Wen nonlinear
    term, here one that softens the saturation of large ``z``:

    >>> def soft(q, z_abs):
    ...     return 1.0 / (1.0 + z_abs / q[0])
    >>> class SoftSaturation(Effect):
    ...     name = "soft_saturation"
    ...     stage = "hysteresis"
    ...     parameters = (Parameter("z_soft", "N", 50.0, HalfNormal(100.0),
    ...                             bounds=(1e-3, 1e4)),)
    ...     description = "Saturation of z that weakens at large z."
    ...     physics = staticmethod(soft)
    """

    name: ClassVar[str] = ""
    stage: ClassVar[str] = ""
    parameters: ClassVar[tuple[Parameter, ...]] = ()
    description: ClassVar[str] = ""
    physics: ClassVar[object] = None
    inverse: ClassVar[object] = None
    reads_z: ClassVar[bool] = False
    state: ClassVar[str | None] = None
    advance: ClassVar[object] = None

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if not cls.name:  # abstract intermediate class
            return
        where = f"effect class {cls.__qualname__}"
        if not cls.name.isidentifier():
            raise EffectError(f"{where}: name {cls.name!r} must be a Python identifier")
        if cls.stage not in STAGES:
            raise EffectError(f"{where}: stage {cls.stage!r} must be one of {STAGES}")
        if not isinstance(cls.parameters, tuple) or not all(
            isinstance(p, Parameter) for p in cls.parameters
        ):
            raise EffectError(f"{where}: parameters must be a tuple of Parameter")
        names = [p.name for p in cls.parameters]
        if len(set(names)) != len(names):
            raise EffectError(f"{where}: duplicate parameter names {names}")
        fn = cls.__dict__.get("physics")
        if isinstance(fn, staticmethod):
            fn = fn.__func__
        if fn is None or not callable(fn):
            raise EffectError(
                f"{where}: set `physics = staticmethod(function)`; see pmabayes.effects"
            )
        cls.physics = staticmethod(_compiled(fn))
        inv = cls.__dict__.get("inverse")
        if isinstance(inv, staticmethod):
            inv = inv.__func__
        if inv is not None:
            if cls.stage != "measurement" or not callable(inv):
                raise EffectError(f"{where}: only a measurement effect may set `inverse = "
                                  "staticmethod(function)`; see pmabayes.effects")
            cls.inverse = staticmethod(_compiled(inv))
        _check_extended(cls, where)

    @classmethod
    def history_s(cls, q: np.ndarray) -> np.ndarray:
        """Seconds of pressure command history the effect needs, per parameter row.

        The closed loop restarts a pressure effect at every command update from
        this much of the past command, each run from its own parameters.

        Parameters
        ----------
        q : numpy.ndarray
            The effect's parameter values, ``(batch, n_params)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``: 2 s for a pressure effect (a guess, for effects that do not
            say), 0 for the other stages.
        """
        return np.full(np.shape(q)[0], 2.0 if cls.stage == "pressure" else 0.0)

    @classmethod
    def lead_s(cls, q: np.ndarray) -> np.ndarray:
        """Lead time the effect adds on the pressure path, per parameter row.

        Computed torque predicts the reference and the position this far ahead
        (the leads of all its model's pressure effects added up).

        Parameters
        ----------
        q : numpy.ndarray
            The effect's parameter values, ``(batch, n_params)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)`` in s; zeros by default (nothing predicted).
        """
        return np.zeros(np.shape(q)[0])

    @classmethod
    def add_delay(cls, q: np.ndarray, delay_s: float) -> np.ndarray | None:
        """The parameter rows with ``delay_s`` more dead time, if the effect can take it.

        The gain rule's delay margin lengthens the plant's delay with this hook.

        Parameters
        ----------
        q : numpy.ndarray
            The effect's parameter values, ``(batch, n_params)``.
        delay_s : float
            Extra delay in s.

        Returns
        -------
        numpy.ndarray or None
            New ``(batch, n_params)`` rows; None (the default) when the effect cannot
            absorb a delay.
        """
        return None

    @classmethod
    def parameter_names(cls) -> tuple[str, ...]:
        """Names of the effect's parameters, in declaration order."""
        return tuple(p.name for p in cls.parameters)

    @classmethod
    def null_values(cls) -> dict[str, float]:
        """Parameter values at which the effect vanishes (for the varying parameters)."""
        return {p.name: p.null for p in cls.parameters if p.vary and p.null is not None}

    @classmethod
    def extended(cls) -> bool:
        """Whether ``physics`` has the extended force signature (reads ``z`` or has a state)."""
        return cls.stage == "force" and (bool(cls.reads_z) or cls.state is not None)

    @classmethod
    def force_n(cls, q: np.ndarray, x_m: float, v_m_s: float, p_pa: float,
                z_n: float = 0.0, state: float = 0.0) -> tuple[float, float, float]:
        """A force effect's force and its ``x`` and ``v`` derivatives, whatever its signature.

        For Python callers (operating points); the simulator inlines ``physics``.

        Parameters
        ----------
        q : numpy.ndarray
            The effect's parameter values, ``(n_params,)``.
        x_m, v_m_s, p_pa : float
            Position, velocity and acting pressure.
        z_n, state : float
            Hysteretic force and the effect's state (used by extended effects only).

        Returns
        -------
        tuple of float
            ``(force_n, dforce_dx, dforce_dv)``.
        """
        if cls.stage != "force":
            raise EffectError(f"effect {cls.name!r} is a {cls.stage} effect, not a force")
        if cls.extended():
            r = cls.physics(q, x_m, v_m_s, p_pa, z_n, state)
        else:
            r = cls.physics(q, x_m, v_m_s, p_pa)
        return float(r[0]), float(r[1]), float(r[2])

    def __repr__(self) -> str:
        return f"<effect {self.name} ({self.stage}): {', '.join(self.parameter_names())}>"


def _check_extended(cls: type[Effect], where: str) -> None:
    """Validate ``reads_z``, ``state`` and ``advance`` (see the module docstring)."""
    if not isinstance(cls.reads_z, bool | np.bool_):
        raise EffectError(f"{where}: reads_z must be True or False, got {cls.reads_z!r}")
    if cls.stage != "force" and (cls.reads_z or cls.state is not None):
        raise EffectError(f"{where}: only a force effect may set reads_z or state (this one "
                          f"is a {cls.stage} effect); see pmabayes.effects")
    adv = cls.__dict__.get("advance")
    if isinstance(adv, staticmethod):
        adv = adv.__func__
    if cls.state is None:
        if adv is not None:
            raise EffectError(f"{where}: `advance` is for an effect with a state; set "
                              "`state = \"name\"` too, or drop `advance`")
        return
    if not (isinstance(cls.state, str) and cls.state.isidentifier()):
        raise EffectError(f"{where}: state must be the state's name, a Python identifier, "
                          f"got {cls.state!r}")
    if adv is None or not callable(adv):
        raise EffectError(
            f"{where}: an effect with state {cls.state!r} must set `advance = "
            "staticmethod(function)`, advance(q, state, x0_m, x1_m, h_s) -> (new_state, "
            "dnew_state_dx1); see pmabayes.effects")
    cls.advance = staticmethod(_compiled(adv))


def _compiled(fn):
    if isinstance(fn, numba.core.registry.CPUDispatcher):
        return fn
    return numba.njit(error_model="numpy")(fn)


_REGISTRY: dict[str, type[Effect]] = {}


def register_effect(effect: type[Effect], *, replace: bool = False) -> type[Effect]:
    """Add an effect class to the registry so it can be named in the API and CLI.

    Parameters
    ----------
    effect : type
        A subclass of :class:`Effect`.
    replace : bool
        Allow replacing a different class already registered under the same name.
        A class with the same module and qualified name (the same definition
        imported again) always replaces the old one.

    Returns
    -------
    type
        ``effect`` itself, so this can be used as a class decorator.

    Raises
    ------
    EffectError
        If ``effect`` is not an Effect subclass, or its name is taken by another class.
    """
    if not (isinstance(effect, type) and issubclass(effect, Effect) and effect.name):
        raise EffectError(f"register_effect needs an Effect subclass with a name, got {effect!r}")
    old = _REGISTRY.get(effect.name)
    # the same definition imported again (a reloaded plugin, a re-run notebook cell)
    redefined = old is not None and (old.__module__, old.__qualname__) == (
        effect.__module__, effect.__qualname__)
    if old is not None and old is not effect and not (replace or redefined):
        raise EffectError(
            f"an effect named {effect.name!r} is already registered ({old.__module__}."
            f"{old.__qualname__}); choose another name or pass replace=True"
        )
    _REGISTRY[effect.name] = effect
    return effect


def registered_effects() -> dict[str, type[Effect]]:
    """All registered effects by name.

    Returns
    -------
    dict
        Name to effect class, built-in and user-registered.
    """
    return dict(_REGISTRY)


def get_effect(name: str) -> type[Effect]:
    """Look up a registered effect by name.

    Parameters
    ----------
    name : str
        Registry name, e.g. ``"regulator_lag"``.

    Returns
    -------
    type
        The effect class.

    Raises
    ------
    EffectError
        If no effect of that name is registered; the message lists the known ones.
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        known = ", ".join(sorted(_REGISTRY))
        raise EffectError(f"unknown effect {name!r}; known effects: {known}") from None


def resolve_effects(effects: Iterable[str | type[Effect] | Effect] | str | None) -> tuple:
    """Turn names, classes or instances (or a comma-separated string) into effect classes.

    Parameters
    ----------
    effects : iterable, str or None
        Names, Effect subclasses or instances; or one comma-separated string.

    Returns
    -------
    tuple of type
        The effect classes in the given order.

    Raises
    ------
    EffectError
        On an unknown name, a non-effect, or the same effect listed twice.
    """
    if effects is None:
        return ()
    if isinstance(effects, str):
        effects = [e.strip() for e in effects.split(",") if e.strip()]
    out: list[type[Effect]] = []
    for e in effects:
        if isinstance(e, str):
            cls = get_effect(e)
        elif isinstance(e, Effect):
            cls = type(e)
        elif isinstance(e, type) and issubclass(e, Effect) and e.name:
            cls = e
        else:
            raise EffectError(f"not an effect: {e!r}")
        if cls in out:
            raise EffectError(f"effect {cls.name!r} is listed twice")
        out.append(cls)
    return tuple(out)


# ---------------------------------------------------------------------------------
# Built-in effects


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


@numba.njit(cache=True, error_model="numpy", inline="always")
def _expm1_over(q):
    # (e^q - 1) / q for |q| <= 0.625: its Taylor series to q^12, in Horner's form
    phq = 1.0 + q * (1 / 2 + q * (1 / 6 + q * (1 / 24 + q * (1 / 120 + q * (1 / 720 + q * (
        1 / 5040 + q * (1 / 40320 + q * (1 / 362880 + q * (1 / 3628800 + q * (
            1 / 39916800 + q * (1 / 479001600 + q / 6227020800)))))))))))
    return phq


@numba.njit(cache=True, error_model="numpy", inline="always")
def smooth_sign(u):
    """Hyperbolic tangent from polynomials only, so that loops calling it vectorise.

    libm's ``tanh`` is an opaque call that stops numba's loops from vectorising.

    Parameters
    ----------
    u : float
        Argument.

    Returns
    -------
    float
        ``tanh(u)`` to a relative error below 1e-13.
    """
    a = abs(u)
    a = a if a < 40.0 else 40.0  # builtin min() would block vectorisation
    q = -a / 64.0  # e^(-2a) = e^(128 q), |q| <= 0.625
    phq = _expm1_over(q)
    # e^(128 q) - 1 = q phq (e + 1)(e^2 + 1)...(e^64 + 1), free of cancellation
    e1 = 1.0 + q * phq
    e2 = e1 * e1
    e4 = e2 * e2
    e8 = e4 * e4
    e16 = e8 * e8
    e32 = e16 * e16
    e64 = e32 * e32
    prod = phq * (e1 + 1.0) * (e2 + 1.0) * (e4 + 1.0) * (e8 + 1.0) * (e16 + 1.0)
    prod *= (e32 + 1.0) * (e64 + 1.0)
    t = a * prod / 64.0 / (1.0 + e64 * e64)
    return t if u >= 0.0 else -t


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


@numba.njit(cache=True, error_model="numpy")
def _position_offset(q, time_s, position_m):
    n, batch = position_m.shape
    for k in range(n):
        for i in range(batch):
            position_m[k, i] += q[i, 0]


@numba.njit(cache=True, error_model="numpy")
def _position_offset_inverse(q, time_s, reading_m):
    return reading_m - q[0], 1.0


@register_effect
class RegulatorLag(Effect):
    """First-order lag of the pressure regulator."""

    name = "regulator_lag"
    stage = "pressure"
    parameters = (
        Parameter(
            "tau_reg", "s", 0.04, LogNormal(0.03, 1.0), bounds=(0.0, 1.0), null=0.0,
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


@register_effect
class TransportDelay(Effect):
    """Dead time between the pressure command and the actuator."""

    name = "transport_delay"
    stage = "pressure"
    parameters = (
        Parameter(
            "t_delay", "s", 0.02, LogNormal(0.02, 1.0), bounds=(0.0, 0.5), null=0.0,
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


@register_effect
class CoulombFriction(Effect):
    """Smooth Coulomb friction of the carriage and the braid."""

    name = "coulomb_friction"
    stage = "force"
    parameters = (
        Parameter(
            "F_c", "N", 1.0, HalfNormal(5.0), bounds=(0.0, 100.0), null=0.0,
            description="Coulomb friction force opposing motion (carriage, rail, braid)",
            latex=r"F_\mathrm{c}",
        ),
        Parameter(
            "v_c", "m/s", 2e-3, LogNormal(2e-3, 1.0), bounds=(1e-6, 1.0), vary=False,
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


@register_effect
class CubicStiffness(Effect):
    """Stiffness that grows (or softens) with extension."""

    name = "cubic_stiffness"
    stage = "force"
    parameters = (
        Parameter(
            "K3", "N/m^3", 2e4, Normal(0.0, 5e4), bounds=(-1e7, 1e7), null=0.0,
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


@register_effect
class PressureStiffness(Effect):
    """Stiffness that grows with the pressure in the muscle."""

    name = "pressure_stiffness"
    stage = "force"
    parameters = (
        Parameter(
            "K_p", "N/(m Pa)", 3e-4, HalfNormal(1e-3), bounds=(0.0, 1e-2), null=0.0,
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


@register_effect
class PositionOffset(Effect):
    """Zero offset of the position sensor."""

    name = "position_offset"
    stage = "measurement"
    parameters = (
        Parameter(
            "x_offset", "m", 5e-4, Normal(0.0, 2e-3), bounds=(-0.05, 0.05), null=0.0,
            description="constant offset of the encoder's zero from the unloaded length",
            latex=r"x_\mathrm{off}",
        ),
    )
    description = (
        "The encoder was zeroed away from the unloaded length, so every measured "
        "position is shifted by x_offset. In the residual: a constant bias, the same at "
        "every frequency, pressure and position."
    )
    physics = staticmethod(_position_offset)
    inverse = staticmethod(_position_offset_inverse)


# ---------------------------------------------------------------------------------
# The PMA's own physics (issue 12): Stribeck friction, the McKibben force-length law
# and a second-order regulator. Each fits an existing stage unchanged.


@numba.njit(cache=True, error_model="numpy", inline="always")
def _exp_neg(a):
    # exp(-a) for a >= 0 from polynomials only, like smooth_sign, so that the loop that
    # calls it vectorises (relative error below 1e-11; exp(-80) ~ 2e-35 beyond a = 80)
    a = a if a < 80.0 else 80.0
    q = -a / 128.0
    phq = _expm1_over(q)
    e = 1.0 + q * phq
    for _ in range(7):
        e = e * e
    return e


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


@register_effect
class StribeckFriction(Effect):
    """Friction whose static level exceeds the kinetic one (the Stribeck effect)."""

    name = "stribeck_friction"
    stage = "force"
    parameters = (
        Parameter(
            "F_k", "N", 0.5, HalfNormal(5.0), bounds=(0.0, 100.0), null=0.0,
            description="kinetic (sliding) friction force, reached well above the "
            "Stribeck velocity",
            latex=r"F_\mathrm{k}",
        ),
        Parameter(
            "F_s", "N", 0.5, HalfNormal(5.0), bounds=(0.0, 100.0), null=0.0,
            description="static friction in excess of the kinetic: breakaway force "
            "F_k + F_s",
            latex=r"F_\mathrm{s}",
        ),
        Parameter(
            "v_s", "m/s", 0.01, LogNormal(0.01, 1.0), bounds=(1e-4, 1.0),
            description="Stribeck velocity over which the static excess decays, "
            "exp(-(v/v_s)^2); not tested when the friction is absent",
            latex=r"v_\mathrm{s}",
        ),
        Parameter(
            "v_st", "m/s", 2e-3, LogNormal(2e-3, 1.0), bounds=(1e-6, 1.0), vary=False,
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


@register_effect
class McKibbenForce(Effect):
    """The McKibben muscle's force per unit pressure falling with extension."""

    name = "mckibben_force"
    stage = "force"
    parameters = (
        Parameter(
            "a_mck", "m^2", 2e-5, HalfNormal(1e-4), bounds=(0.0, 1e-3), null=0.0,
            description="area lost per ((1 + x/l_0)^2 - 1) of extension: Chou-Hannaford's "
            "3 l_0^2 / (4 pi n^2) for a braid of n turns",
            latex=r"a_\mathrm{mck}",
        ),
        Parameter(
            "l_0", "m", 0.17, LogNormal(0.17, 0.5), bounds=(1e-3, 10.0), vary=False,
            description="unactuated muscle length (the paper's 170 mm)",
            latex=r"l_0",
        ),
        Parameter(
            "p_mck", "Pa", 66922.0, Normal(66922.0, 2e4), bounds=(0.0, 3e5), vary=False,
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


@register_effect
class RegulatorSecondOrder(Effect):
    """Second-order (possibly ringing) pressure regulator."""

    name = "regulator_second_order"
    stage = "pressure"
    parameters = (
        Parameter(
            "tau_n", "s", 0.01, LogNormal(0.01, 1.0), bounds=(0.0, 1.0), null=0.0,
            description="inverse natural frequency 1/omega_n of the regulator's "
            "second-order response",
            latex=r"\omega_n^{-1}",
        ),
        Parameter(
            "zeta_reg", "1", 0.7, LogNormal(0.7, 0.7), bounds=(0.02, 20.0),
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



# ---------------------------------------------------------------------------------
# Effects that read z, carry a state, or change the hysteresis law (issue 12), and
# the polynomial-only helpers that keep their kernels vectorised (libm calls such as
# exp, log and pow stop numba's batch loop from vectorising)


@intrinsic
def _bits(typingctx, x):
    # the int64 with a float64's bits (LLVM bitcast; numba has no scalar one)
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@intrinsic
def _from_bits(typingctx, n):
    # the float64 with an int64's bits
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


@numba.njit(cache=True, error_model="numpy", inline="always")
def decay(y):
    """``exp(-y)`` and ``(1 - exp(-y)) / y`` for ``y >= 0``, from polynomials only.

    ``-y = n ln 2 + r``: ``n`` rounded by the ``1.5 * 2^52`` shift, ``r`` (``|r| <=
    0.347``) with ``ln 2`` in two parts, ``e^r`` a Taylor polynomial and ``2^n`` built
    from bits, as in :func:`power`.

    Parameters
    ----------
    y : float
        Argument, ``>= 0`` (a step over a time constant, say).

    Returns
    -------
    tuple of float
        ``(exp(-y), (1 - exp(-y)) / y)``, to a relative error below 2e-15 for
        ``y <= 40`` (the first is 0 beyond, an absolute error below 5e-18; the
        second is 1 at ``y = 0``, without cancellation for small ``y``).
    """
    a = y if y < 40.0 else 40.0  # builtin min() would block vectorisation
    # -a = n ln 2 + r, n = round(-a / ln 2) by the 1.5 * 2^52 shift, |r| <= 0.347
    s = a * -1.4426950408889634 + 6755399441055744.0
    n = s - 6755399441055744.0
    r = (n * -0.6931471803691238 - a) - n * 1.9082149292705877e-10  # ln 2 in two parts
    # e^r = 1 + r p, p = sum r^i / (i + 1)!, i <= 11
    r2 = r * r
    r4 = r2 * r2
    r8 = r4 * r4
    p = ((1.0 + r / 2) + r2 * (1 / 6 + r / 24)) + r4 * (
        (1 / 120 + r / 720) + r2 * (1 / 5040 + r / 40320))
    p = p + r8 * ((1 / 362880 + r / 3628800) + r2 * (1 / 39916800 + r / 479001600))
    ex = _from_bits((_bits(s) + 1023) << 52) * (1.0 + r * p)  # n in s's low bits
    # n = 0 (a < 0.347): r = -a exactly and (1 - e^-a) / a = p, without cancellation;
    # else 1 - e^-a >= 0.29
    far = (1.0 - ex) / (y if y > 0.34 else 0.34)
    return (ex if y <= 40.0 else 0.0), (p if n == 0.0 else far)


@numba.njit(cache=True, error_model="numpy", inline="always")
def power(y, e):
    """``y ** e`` for ``y > 0``, from bit operations and polynomials only (vectorises).

    ``e log2 y``: exponent and mantissa ``m`` from ``y``'s bits, ``m = 2^(j/4) (1 + f)``
    with ``j`` chosen by comparisons (selects) so that ``|f| <= 0.0905``, then a Taylor
    polynomial of ``log2(1 + f)``; ``2^v``: ``v = n + r`` with ``n`` rounded by the
    ``1.5 * 2^52`` shift, a Taylor polynomial of ``2^r`` and ``2^n`` built from bits.
    No division and no int/float conversion (AVX2 has no packed int64 -> double);
    the polynomials in Estrin's scheme, as the caller's batch loop is latency-bound.

    Parameters
    ----------
    y : float
        Base, in ``[2^-60, 2^60]`` (about ``[1e-18, 1e18]``; clamped to it).
    e : float
        Exponent, with ``|e ln y| <= 40`` (``e ln y`` is clamped to it).

    Returns
    -------
    float
        ``y ** e`` to a relative error below 3e-14 over that domain.
    """
    r = y if y > 8.673617379884035e-19 else 8.673617379884035e-19
    r = r if r < 1.152921504606847e18 else 1.152921504606847e18
    b = _bits(r)
    # exponent as a double: 2^52 + biased exponent in the bits of 2^52, minus both
    k = _from_bits((b >> 52) | 0x4330000000000000) - 4503599627371519.0
    m = _from_bits((b & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)  # in [1, 2)
    # m = 2^(j/4) m', |m' - 1| <= 0.0905: log2 m = j/4 + log2(1 + f), f = m' - 1
    c = 0.5 if m >= 1.8340080864093424 else 0.5946035575013605
    c = c if m >= 1.5422108254079407 else 0.7071067811865476
    c = c if m >= 1.2968395546510096 else 0.8408964152537145
    c = c if m >= 1.0905077326652577 else 1.0
    j = 1.0 if m >= 1.8340080864093424 else 0.75
    j = j if m >= 1.5422108254079407 else 0.5
    j = j if m >= 1.2968395546510096 else 0.25
    j = j if m >= 1.0905077326652577 else 0.0
    f = m * c - 1.0
    # log2(1 + f) = (f - f^2/2 + ... - f^14/14) / ln 2
    f2 = f * f
    f4 = f2 * f2
    f8 = f4 * f4
    a = (1.4426950408889634 - 0.7213475204444817 * f) + f2 * (
        0.48089834696298783 - 0.36067376022224085 * f)
    a = a + f4 * ((0.28853900817779266 - 0.24044917348149392 * f) + f2 * (
        0.20609929155556622 - 0.18033688011112042 * f))
    d = (0.1602994489876626 - 0.14426950408889633 * f) + f2 * (
        0.1311540946262694 - 0.12022458674074696 * f)
    d = d + f4 * (0.11097654160684335 - 0.10304964577778311 * f)
    v = e * ((k + j) + f * (a + f8 * d))  # e log2 y
    v = v if v < 57.70780163555854 else 57.70780163555854  # |e ln y| <= 40
    v = v if v > -57.70780163555854 else -57.70780163555854
    s = v + 6755399441055744.0  # n + 1.5 * 2^52, n = round(v)
    r = v - (s - 6755399441055744.0)  # exact, |r| <= 1/2
    # 2^r = sum (r ln 2)^i / i!, i <= 13
    r2 = r * r
    r4 = r2 * r2
    r8 = r4 * r4
    a = (1.0 + 0.6931471805599453 * r) + r2 * (0.2402265069591007 + 0.055504108664821576 * r)
    d = (0.009618129107628477 + 0.0013333558146428441 * r) + r2 * (
        0.00015403530393381606 + 1.5252733804059838e-05 * r)
    g = (1.3215486790144305e-06 + 1.0178086009239696e-07 * r) + r2 * (
        7.054911620801121e-09 + 4.44553827187081e-10 * r)
    p = (a + r4 * d) + r8 * (g + r4 * (2.5678435993488196e-11 + 1.3691488853904124e-12 * r))
    return p * _from_bits((_bits(s) + 1023) << 52)  # n in s's low bits: 2^n


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


@numba.njit(cache=True, error_model="numpy")
def _bouc_wen_exponent(q, z_abs):
    # |z| (|z| / z_ref)^(n - 1) = |z|^n z_ref^(1 - n): the factor g of c |z| g; the
    # floor keeps g finite at z = 0 for n < 1, where c |z| g vanishes anyway
    y = z_abs / q[1]
    return power(y if y > 1e-6 else 1e-6, q[0] - 1.0)


@register_effect
class PressureHysteresis(Effect):
    """Hysteretic force that grows with pressure (braid-bladder friction)."""

    name = "pressure_hysteresis"
    stage = "force"
    reads_z = True
    parameters = (
        Parameter(
            "kappa_ph", "1", 0.3, HalfNormal(1.0), bounds=(0.0, 10.0), null=0.0,
            description="growth of the hysteretic force with pressure: z (1 + kappa_ph "
            "p / p_ref_ph)",
            latex=r"\kappa_\mathrm{ph}",
        ),
        Parameter(
            "p_ref_ph", "Pa", 5e5, LogNormal(5e5, 1.0), bounds=(1e3, 1e7), vary=False,
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


@register_effect
class MaxwellCreep(Effect):
    """A spring and a dashpot in series, beside the muscle: viscoelastic creep."""

    name = "maxwell_creep"
    stage = "force"
    state = "u_m"
    parameters = (
        Parameter(
            "k_m", "N/m", 200.0, HalfNormal(500.0), bounds=(0.0, 1e5), null=0.0,
            description="stiffness of the creep element's spring (in series with its "
            "dashpot, the pair beside the muscle)",
            latex=r"k_\mathrm{m}",
        ),
        Parameter(
            "tau_m", "s", 0.2, LogNormal(0.2, 1.0), bounds=(1e-3, 100.0), vary=False,
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


@register_effect
class BoucWenExponent(Effect):
    """The generalised Bouc-Wen exponent n in |z|^n."""

    name = "bouc_wen_exponent"
    stage = "hysteresis"
    parameters = (
        Parameter(
            "n_bw", "1", 1.0, Normal(1.0, 0.1), bounds=(0.7, 1.5), null=1.0,
            description="Bouc-Wen exponent: dz/dx = alpha - c |z| (|z| / z_ref_bw)^(n_bw "
            "- 1); 1 is the paper's model",
            latex=r"n_\mathrm{BW}",
        ),
        Parameter(
            "z_ref_bw", "N", 10.0, LogNormal(10.0, 1.0), bounds=(1e-3, 1e4), vary=False,
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
