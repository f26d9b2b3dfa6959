"""The extension point: :class:`Effect`, one small class per physical effect, and the
stages of the signal path it may act at (:data:`STAGES`). The theory page
(docs, Physical effects) gives each stage's physics signature.
"""

from __future__ import annotations

from typing import ClassVar

import numba
import numpy as np

from pmabayes.model.parameters import Parameter

__all__ = ["STAGES", "EffectError", "Effect"]


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
        Optional, force and hysteresis effects: the name of the effect's one internal
        state (starting at 0 at rest); ``physics`` then has the extended signature
        and ``advance`` must be set. From an estimated start the state is estimated
        too where :meth:`start_state` gives it a prior.
    advance : callable or None
        With ``state``: for a force effect the state's exact change over one step,
        ``advance(q, state, x0_m, x1_m, h_s) -> (new_state, dnew_state_dx1)``; for a
        hysteresis effect its change while ``z`` runs from ``z0_n`` to ``z1_n`` over
        the displacement ``dx_m``, ``advance(q, state, z0_n, z1_n, dx_m) ->
        new_state``. Compiled like ``physics``.

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
    ...                             bounds=(0.0, np.inf)),)
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
    ...         Parameter("k_sensor", "1", 1.0, Normal(1.0, 0.1)),
    ...         Parameter("b_sensor", "m", 0.0, Normal(0.0, 1e-3), bounds=(-0.01, 0.01)))
    ...     description = "Sensor gain and offset."
    ...     physics = staticmethod(gain_offset)
    ...     inverse = staticmethod(gain_offset_inverse)

    A force that reads ``z`` and carries a state: a spring ``k`` in series with a
    dashpot of time constant ``tau``, whose stretch ``u`` relaxes as
    ``u' = x' - u / tau`` (exact over a step with ``x`` linear in time):

    >>> from pmabayes.model.effects import decay
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
    ...         Parameter("tau_slow", "s", 2.0, HalfNormal(5.0), bounds=(0.0, np.inf),
    ...                   vary=False))
    ...     description = "Spring and dashpot in series, beside the muscle."
    ...     physics = staticmethod(creep)
    ...     advance = staticmethod(creep_advance)

    A hysteresis effect returns the factor ``g(|z|)`` of the Bouc-Wen nonlinear
    term (with a state, the factors of ``alpha`` and of that term: see
    :class:`~pmabayes.model.effects.BoucWenBaberNoori`), here one that softens the
    saturation of large ``z``:

    >>> def soft(q, z_abs):
    ...     return 1.0 / (1.0 + z_abs / q[0])
    >>> class SoftSaturation(Effect):
    ...     name = "soft_saturation"
    ...     stage = "hysteresis"
    ...     parameters = (Parameter("z_soft", "N", 50.0, HalfNormal(100.0),
    ...                             bounds=(0.0, np.inf)),)
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
                f"{where}: set `physics = staticmethod(function)`; see pmabayes.model.effects"
            )
        cls.physics = staticmethod(_compiled(fn))
        inv = cls.__dict__.get("inverse")
        if isinstance(inv, staticmethod):
            inv = inv.__func__
        if inv is not None:
            if cls.stage != "measurement" or not callable(inv):
                raise EffectError(f"{where}: only a measurement effect may set `inverse = "
                                  "staticmethod(function)`; see pmabayes.model.effects")
            cls.inverse = staticmethod(_compiled(inv))
        _check_extended(cls, where)

    @classmethod
    def force_rig_priors(cls, stiffness_n_m: float, amplitude_m: float,
                         moving_mass_kg: float) -> dict:
        """Priors of the effect's parameters on a force-input rig, on its data's scale.

        A force-driven oscillator can be anything from a benchmark's 2 kg to a
        concrete column, so an effect whose default priors are the muscle's says
        here how they scale (:func:`pmabayes.model.model.force_rig_priors`). The
        default keeps the declared priors.

        Parameters
        ----------
        stiffness_n_m : float
            The data's static stiffness (inverse compliance of position on force).
        amplitude_m : float
            Half the position's range.
        moving_mass_kg : float
            The rig's moving mass.

        Returns
        -------
        dict
            Parameter name to :class:`~pmabayes.model.parameters.Prior`.
        """
        return {}

    @classmethod
    def start_state(cls, *, force_n: float, motion_m: float, work_j: float
                    ) -> Parameter | None:
        """The effect's state at an estimated start, as a parameter with its prior.

        A record that starts mid-test (``"initial_state": "estimate"``) has its start
        estimated: the position, velocity and hysteretic force, and each effect's
        state through this method. An effect with a :attr:`state` whose value there
        the data can say returns it as a parameter, its prior on the data's scale
        (a degradation's dissipated energy, a creep element's stretch); None (the
        default) keeps the state at 0, its value at rest, which the start's report
        then says.

        Parameters
        ----------
        force_n : float
            The record's range of force on the actuator (area times the pressure's
            range on a pressure rig).
        motion_m : float
            The record's range of motion.
        work_j : float
            The work the actuator's force does over the record, summed in absolute
            value (the sum of ``|F dx|`` of the trial mean).

        Returns
        -------
        Parameter or None
        """
        return None

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
            As :meth:`history_s`'s.

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
    if cls.stage != "force" and cls.reads_z:
        raise EffectError(f"{where}: only a force effect may set reads_z (this one is a "
                          f"{cls.stage} effect); see pmabayes.model.effects")
    if cls.stage not in ("force", "hysteresis") and cls.state is not None:
        raise EffectError(f"{where}: only a force or a hysteresis effect may set state (this "
                          f"one is a {cls.stage} effect); see pmabayes.model.effects")
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
        signature = ("advance(q, state, z0_n, z1_n, dx_m) -> new_state"
                     if cls.stage == "hysteresis" else
                     "advance(q, state, x0_m, x1_m, h_s) -> (new_state, dnew_state_dx1)")
        raise EffectError(
            f"{where}: an effect with state {cls.state!r} must set `advance = "
            f"staticmethod(function)`, {signature}; see pmabayes.model.effects")
    cls.advance = staticmethod(_compiled(adv))


def _compiled(fn):
    if isinstance(fn, numba.core.registry.CPUDispatcher):
        return fn
    return numba.njit(error_model="numpy")(fn)
