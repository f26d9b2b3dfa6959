"""The PMA model: base physics, the rig it runs on, and composed effects.

The base model is equation (1)-(2) of Godage et al. (dynamic control of PMAs) with
the viscous damping ``d x'`` that the paper identifies but leaves out of (1)::

    (M + m) x'' + d x' + (M + m) g s_g + K_e x + z = A max(p - p_dz, 0)
    z' = x' [alpha - (beta sgn(x' z) + gamma) |z|]

in SI units (m, s, Pa, N, kg). ``x`` is the length change from the unloaded length,
``z`` the Bouc-Wen hysteretic force (N), so ``alpha`` is in N/m and ``beta``,
``gamma`` in 1/m (the paper calls them dimensionless). ``s_g = +1`` when gravity
opposes extension (the characterisation rig), ``-1`` when it pulls toward extension
(the control rig with its 500 g load), 0 without gravity.

A :class:`Rig` holds what is known and fixed (masses, area, gravity); a
:class:`Model` composes the base physics with :mod:`pmabayes.model.effects`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from pmabayes.data import DataWarning
from pmabayes.data.rig import (  # the rig's schema (RIG_* re-exported from here too)
    DEFAULT_INPUT_KIND,
    INPUT_OF_KIND,
    RIG_DICT_KEYS,
    RIG_KEYS,
    RIG_PRIOR_KEYS,
    declared_rig,
    rig_problem,
)
from pmabayes.data.sidecar import say_once
from pmabayes.model.boucwen import loading_branch
from pmabayes.model.effects import Effect, resolve_effects
from pmabayes.model.parameters import (
    HalfNormal,
    LogNormal,
    Normal,
    Parameter,
    Prior,
    Uniform,
    parse_prior,
)

__all__ = [
    "G_M_S2",
    "ENCODER_COUNTS_PER_M",
    "PAPER_VALUES",
    "PMA_MASS_KG",
    "CARRIAGE_MASS_KG",
    "CONTROL_LOAD_KG",
    "PAPER_EXTENSION_M",
    "PAPER_EXTENSION_PRESSURE_PA",
    "derive_area",
    "PAPER_AREA_M2",
    "BASE_PARAMETERS",
    "RIG_PRIOR_KEYS",
    "RIG_PREFIX",
    "RIG_DICT_KEYS",
    "RIG_KEYS",
    "assumed_rig",
    "force_rig_priors",
    "Rig",
    "Model",
    "ModelError",
]

#: warnings point at the caller's line, outside the package
_PACKAGE = (str(Path(__file__).parents[1]),)

G_M_S2 = 9.81
PMA_MASS_KG = 0.022
CARRIAGE_MASS_KG = 0.045
CONTROL_LOAD_KG = 0.5
PAPER_EXTENSION_M = 0.085
PAPER_EXTENSION_PRESSURE_PA = 0.4e6
#: The paper's linear encoder: 2000 quadrature counts per inch.
ENCODER_COUNTS_PER_M = 2000 / 0.0254

#: The paper's point estimate (GlobalSearch + fmincon on the trial-mean RMS error).
PAPER_VALUES: dict[str, float] = {
    "alpha": 23.705,
    "beta": 1.7267,
    "gamma": -42.593,
    "d": 155.76,
    "K_e": 624.78,
    "p_dz": 66.922e3,
}


class ModelError(ValueError):
    """A model is composed or parameterised wrongly."""


def derive_area(
    *,
    extension_m: float = PAPER_EXTENSION_M,
    pressure_pa: float = PAPER_EXTENSION_PRESSURE_PA,
    moving_mass_kg: float = CARRIAGE_MASS_KG + PMA_MASS_KG,
    gravity_sign: float = 1.0,
    g_m_s2: float = G_M_S2,
    values: Mapping[str, float] | None = None,
) -> float:
    """Effective area ``A`` that gives the paper's steady-state extension.

    The paper reports 85 mm of steady-state extension at 0.4 MPa but not ``A``.
    With the trial convention of this package (start at rest at zero pressure,
    where gravity alone sags the muscle to ``x0 = -(M+m) g s_g / K_e`` with
    ``z = 0``) a pressure step makes ``x`` rise monotonically (the linear part is
    over-damped), so ``z`` follows the loading branch of the Bouc-Wen equation,
    ``dz/dx = alpha - (beta + gamma) z``, whose solution from ``z(x0) = 0`` is::

        z(x) = alpha / c * (1 - exp(-c (x - x0))),   c = beta + gamma.

    ``z`` is rate independent, so after 100 s the static balance holds::

        A (p - p_dz) = K_e x + z(x) + (M + m) g s_g.

    With the paper's values this gives ``A = 2.183e-4 m^2`` (53.11 N of spring,
    18.95 N of hysteretic force and 0.66 N of weight over 333 kPa). Starting the
    hysteretic state at ``x0 = 0`` instead (ignoring the 1 mm sag) gives the
    slightly smaller 2.158e-4 m^2, close to the 2.159e-4 used by
    ``shared/bench/c_reference``.

    Parameters
    ----------
    extension_m : float
        Steady-state ``x`` in m.
    pressure_pa : float
        Step pressure in Pa.
    moving_mass_kg : float
        ``M + m`` in kg.
    gravity_sign : float
        ``s_g``.
    g_m_s2 : float
        Gravitational acceleration.
    values : mapping, optional
        Base parameters; the paper's by default.

    Returns
    -------
    float
        ``A`` in m^2.

    Examples
    --------
    >>> from pmabayes import derive_area
    >>> round(derive_area() * 1e4, 3)  # the paper's rig, in cm^2
    2.183
    >>> round(derive_area(moving_mass_kg=0.567) * 1e4, 3)  # 500 g more to lift
    2.552
    """
    v = dict(PAPER_VALUES if values is None else values)
    weight = moving_mass_kg * g_m_s2 * gravity_sign
    x0 = -weight / v["K_e"]
    z = loading_branch(extension_m - x0, v["alpha"], v["beta"], v["gamma"])
    return (v["K_e"] * extension_m + z + weight) / (pressure_pa - v["p_dz"])


PAPER_AREA_M2 = derive_area()

#: Base parameters, first in every model's parameter order (the simulator finds
#: them by name: :class:`~pmabayes.model.boucwen.BoucWenColumns`).
#:
#: :meta hide-value:
BASE_PARAMETERS: tuple[Parameter, ...] = (
    Parameter(
        "alpha", "N/m", PAPER_VALUES["alpha"], LogNormal(25.0, 1.5), bounds=(0.0, math.inf),
        description="Bouc-Wen initial stiffness of the hysteretic force z",
        latex=r"\alpha",
    ),
    Parameter(
        "beta", "1/m", PAPER_VALUES["beta"], HalfNormal(50.0), bounds=(0.0, math.inf),
        description="Bouc-Wen loop-width coefficient (beta > 0 opens the loop)",
        latex=r"\beta",
    ),
    Parameter(
        "gamma", "1/m", PAPER_VALUES["gamma"], Normal(0.0, 50.0),
        description="Bouc-Wen shape coefficient (beta + gamma < 0 stiffens with extension)",
        latex=r"\gamma",
    ),
    Parameter(
        "d", "N s/m", PAPER_VALUES["d"], LogNormal(150.0, 1.0), bounds=(0.0, math.inf),
        description="viscous damping of the muscle and carriage",
        latex="d",
    ),
    Parameter(
        "K_e", "N/m", PAPER_VALUES["K_e"], LogNormal(600.0, 1.0), bounds=(0.0, math.inf),
        description="linear elastic stiffness of the bladder",
        latex=r"K_e",
    ),
    Parameter(
        "p_dz", "Pa", PAPER_VALUES["p_dz"], Uniform(0.0, 3e5), bounds=(0.0, math.inf),
        description="dead-zone pressure below which the muscle does not extend",
        latex=r"p_\mathrm{dz}",
    ),
)


#: Prefix of the model parameter of a rig value given as a prior.
RIG_PREFIX = "rig_"


@dataclass(frozen=True)
class Rig:
    """The known, fixed constants of a test rig.

    Parameters
    ----------
    moving_mass_kg : float
        ``M + m``: carriage, load and muscle.
    gravity_sign : float
        ``s_g``: +1 gravity opposes extension, -1 pulls toward it, 0 none.
    area_m2 : float
        Effective area ``A`` (force per pressure); 1 for a force-driven oscillator.
    input_kind : str
        ``"pressure"`` (input in Pa, with dead zone) or ``"force"`` (input in N, no
        dead zone, so ``p_dz`` is not a parameter).
    g_m_s2 : float
        Gravitational acceleration.
    name : str
        A label for reports.
    priors : tuple of (str, Prior)
        Rig values that are not known but identified (:data:`RIG_PRIOR_KEYS`), each
        with its prior; the value's field then holds the prior's median (a number
        given for it is replaced). A model on this rig has the parameter ``rig_KEY``
        for each.

    Examples
    --------
    A bench with 250 g moving (the paper's area), then the same bench whose effective
    area is not known but identified from a prior, as a sidecar's ``"rig"`` says it:

    >>> from pmabayes import Model, Rig
    >>> rig = Rig(moving_mass_kg=0.25, name="bench_a")
    >>> Model(["regulator_lag"], rig=rig)
    Model(rig=bench_a, effects=regulator_lag, parameters=7)
    >>> unknown_area = Rig.from_dict({"moving_mass_kg": 0.25, "name": "bench_a",
    ...                               "area_m2": "LogNormal(2e-4, 1.2)"})
    >>> unknown_area.priors
    (('area_m2', LogNormal(median=0.0002, sigma=1.2)),)
    >>> Model(rig=unknown_area).free_names[-1]
    'rig_area_m2'
    >>> Rig.characterisation().moving_mass_kg  # the paper's rig, the default
    0.067
    """

    moving_mass_kg: float
    gravity_sign: float = 1.0
    area_m2: float = PAPER_AREA_M2
    input_kind: str = DEFAULT_INPUT_KIND
    g_m_s2: float = G_M_S2
    name: str = "custom"
    priors: tuple[tuple[str, Prior], ...] = field(default=())

    def __post_init__(self) -> None:
        # the one schema of a rig (pmabayes.data.rig), which a sidecar's is checked with
        problem = rig_problem({f.name: getattr(self, f.name) for f in fields(self)
                               if f.name != "priors"})
        if problem:
            raise ModelError(problem)
        for key, prior in self.priors:
            if key not in RIG_PRIOR_KEYS or not isinstance(prior, Prior):
                raise ModelError(f"rig prior {key!r}: only {', '.join(RIG_PRIOR_KEYS)} may be "
                                 "given as a pmabayes Prior")
            try:
                _rig_parameter(key, prior).check_prior()
            except ValueError as err:
                raise ModelError(f"{key!r}: {err}") from None
            # the field is the prior's median however the rig was made (Rig.from_dict
            # sets it; Rig(priors=...) would keep the paper's area), so that what reads
            # or prints it agrees with the prior; the kernel reads the identified value
            object.__setattr__(self, key, prior.quantile(0.5))

    @classmethod
    def characterisation(cls) -> Rig:
        """The paper's identification rig: carriage + muscle, gravity opposing extension."""
        return cls(CARRIAGE_MASS_KG + PMA_MASS_KG, 1.0, PAPER_AREA_M2, name="characterisation")

    @classmethod
    def control(cls, load_kg: float = CONTROL_LOAD_KG) -> Rig:
        """The paper's control rig: a load hanging so that gravity pulls toward extension."""
        return cls(CARRIAGE_MASS_KG + PMA_MASS_KG + load_kg, -1.0, PAPER_AREA_M2, name="control")

    @classmethod
    def force_oscillator(cls, mass_kg: float) -> Rig:
        """A generic force-driven Bouc-Wen oscillator: ``m x'' + d x' + K_e x + z = u``."""
        return cls(mass_kg, 0.0, 1.0, input_kind="force", name="force_oscillator")

    @property
    def input_name(self) -> str:
        """Name of the input column in data files."""
        return INPUT_OF_KIND[self.input_kind]

    @property
    def gravity_force_n(self) -> float:
        """``(M + m) g s_g``, the gravity term on the left of the equation of motion."""
        return self.moving_mass_kg * self.g_m_s2 * self.gravity_sign

    def to_dict(self) -> dict:
        """JSON-serialisable form (for data sidecars and fit files); a value given as a
        prior is written as the prior's text."""
        out = asdict(self)
        del out["priors"]
        out.update({key: str(prior) for key, prior in self.priors})
        return out

    @classmethod
    def from_dict(cls, d: Mapping) -> Rig:
        """Inverse of :meth:`to_dict`; unknown keys are an error.

        A value of :data:`RIG_PRIOR_KEYS` may be a prior's text
        (:func:`~pmabayes.model.parameters.parse_prior`), e.g. ``"LogNormal(1e-5, 1.5)"``.
        """
        problem = rig_problem(d)
        if problem:
            raise ModelError(problem)
        values, priors = dict(d), []
        for key, value in d.items():
            if key not in RIG_PRIOR_KEYS or not isinstance(value, str):
                continue
            try:
                prior = parse_prior(value)
            except ValueError as err:
                raise ModelError(f"{key!r}: {err}; or give a number") from None
            priors.append((key, prior))
            values[key] = prior.quantile(0.5)
        return cls(**values, priors=tuple(priors))

    def prior_of(self, key: str) -> Prior | None:
        """The prior of rig value ``key``, or None where the value is a number."""
        return dict(self.priors).get(key)


def assumed_rig(dataset) -> None:
    """Say once per file that a data set whose sidecar declares no rig (no ``"rig"``, or
    free-form notes there) runs on the paper's characterisation rig (a
    :class:`~pmabayes.data.DataWarning`).

    Silent for data sets made in Python (no source), synthetic data (their sidecar
    has their rig, or says ``"synthetic"``) and force data (refused without a rig).

    Parameters
    ----------
    dataset : Dataset
        Data whose model is about to get the characterisation rig.

    Warns
    -----
    DataWarning
        Once per file and process, with a complete ``"rig"`` to declare.
    """
    meta = dataset.metadata or {}
    source = dataset.source_file
    if (source is None or declared_rig(meta) is not None or meta.get("synthetic") is True
            or "generator" in meta or dataset.input_name != "pressure_pa"):
        return
    rig = Rig.characterisation()
    example = json.dumps({"rig": {**rig.to_dict(), "name": "my_rig"}})
    # a "rig" of free-form notes (no rig key) declares no rig either
    missing = ('its sidecar\'s "rig" holds notes, not the rig\'s constants' if "rig" in meta
               else 'no "rig" in its sidecar')
    say_once(source, "rig", DataWarning(
        f"{source}: {missing}, so the paper's characterisation rig is "
        f"assumed (moving mass {rig.moving_mass_kg:g} kg, gravity against extension, area "
        f"A={rig.area_m2:.4g} m^2); declare yours in "
        f"{Path(source).with_suffix('.json').name}: {example[1:-1]} (gravity_sign -1: "
        "gravity pulls toward extension, 0: none; a value not known may be a prior, e.g. "
        '"area_m2": "LogNormal(1e-4, 1.5)")'), _PACKAGE)


def _rig_parameter(key: str, prior: Prior) -> Parameter:
    """The model parameter of a rig value given as a prior."""
    unit, meaning = RIG_PRIOR_KEYS[key]
    return Parameter(f"{RIG_PREFIX}{key}", unit, prior.quantile(0.5), prior,
                     bounds=(0.0, math.inf),
                     description=f"the rig's {meaning}, identified (the data's sidecar gives "
                                 "it as a prior)")


def force_rig_priors(compliance_m_per_n: float, amplitude_m: float,
                     moving_mass_kg: float, effects: Iterable = ()) -> dict[str, Prior]:
    """Default priors of a force-input rig, on the scale of its data.

    A force-driven oscillator can be anything from a 2 kg benchmark to a concrete
    wall, so its priors follow the data: stiffnesses from the static compliance
    ``c`` (a linear fit of position on force), each of ``alpha`` and ``K_e`` around
    half of ``1 / c``; ``beta`` and ``gamma`` (1/m) from the motion's amplitude, so
    that the hysteretic force saturates within the motion; the damping around
    ``sqrt(m / c)`` (a damping ratio of 1/2). Each effect puts its own parameters on
    the data's scale (:meth:`pmabayes.model.effects.Effect.force_rig_priors`). The same
    data with the force in other units then give the same fit.

    Parameters
    ----------
    compliance_m_per_n : float
        Static compliance, > 0.
    amplitude_m : float
        Half the position's range, > 0.
    moving_mass_kg : float
        The rig's moving mass.
    effects : iterable of Effect classes
        The model's effects, whose parameters' priors are scaled too.

    Returns
    -------
    dict
        Priors of ``alpha``, ``beta``, ``gamma``, ``d``, ``K_e`` and the effects'
        parameters that scale with the data.
    """
    stiffness = 1.0 / compliance_m_per_n
    per_m = 1.0 / amplitude_m
    out = {
        "alpha": LogNormal(0.5 * stiffness, 2.0),
        "beta": HalfNormal(5.0 * per_m),
        "gamma": Normal(0.0, 5.0 * per_m),
        "d": LogNormal(math.sqrt(moving_mass_kg * stiffness), 2.5),
        "K_e": LogNormal(0.5 * stiffness, 2.0),
    }
    for effect in effects:
        out.update(effect.force_rig_priors(stiffness, amplitude_m, moving_mass_kg))
    return out


class Model:
    """The base PMA model composed with physical effects.

    Parameters
    ----------
    effects : iterable of str, Effect class or instance, or comma-separated str
        Effects to add, in order. Pressure-path effects are applied in this order.
    rig : Rig, optional
        Fixed constants; :meth:`Rig.characterisation` by default.
    priors : mapping of str to Prior, optional
        Overrides of the default priors, by parameter name.
    fixed : mapping of str to float, optional
        Parameters held fixed at the given values (not identified). Settings that
        are fixed by default (``vary=False``) can be freed with ``free``.
    free : iterable of str, optional
        Parameters fixed by default that should be identified.

    Raises
    ------
    ModelError
        If two parameters share a name, or an override names no parameter.

    Examples
    --------
    >>> from pmabayes import Model
    >>> m = Model(["regulator_lag", "coulomb_friction"])
    >>> m.parameter_names
    ('alpha', 'beta', 'gamma', 'd', 'K_e', 'p_dz', 'tau_reg', 'F_c', 'v_c')
    >>> m.free_names[-2:]
    ('tau_reg', 'F_c')
    """

    def __init__(
        self,
        effects: Iterable[str | type[Effect] | Effect] | str | None = None,
        *,
        rig: Rig | None = None,
        priors: Mapping[str, Prior] | None = None,
        fixed: Mapping[str, float] | None = None,
        free: Iterable[str] | None = None,
    ) -> None:
        self.rig = Rig.characterisation() if rig is None else rig
        self.effects: tuple[type[Effect], ...] = resolve_effects(effects)
        laws = [e.name for e in self.effects if e.stage == "hysteresis"]
        if len(laws) > 1:
            raise ModelError(f"effects {', '.join(laws)} each change the hysteresis law; a "
                             "model holds at most one hysteresis effect")
        base = BASE_PARAMETERS
        if self.rig.input_kind == "force":
            base = tuple(p for p in base if p.name != "p_dz")
        params: list[Parameter] = list(base)
        owner = {p.name: "the base model" for p in base}
        for eff in self.effects:
            for p in eff.parameters:
                if p.name in owner:
                    raise ModelError(
                        f"parameter name clash: {p.name!r} of effect {eff.name!r} is already "
                        f"declared by {owner[p.name]}; rename it in the effect"
                    )
                owner[p.name] = f"effect {eff.name!r}"
                params.append(p)
        self._base_count = len(base)
        self._effect_end = len(params)
        for key, prior in self.rig.priors:  # rig values identified with the physics
            params.append(_rig_parameter(key, prior))
        self.parameters: tuple[Parameter, ...] = tuple(params)
        self.parameter_names: tuple[str, ...] = tuple(p.name for p in params)
        self._index = {n: i for i, n in enumerate(self.parameter_names)}
        self.priors: dict[str, Prior] = {p.name: p.prior for p in params}
        for name, prior in (priors or {}).items():
            self._check_name(name, "priors")
            if not isinstance(prior, Prior):
                raise ModelError(f"prior for {name!r} must be a pmabayes Prior, got {prior!r}")
            self.priors[name] = prior
        self.fixed: dict[str, float] = {p.name: p.default for p in params if not p.vary}
        for name in free or ():
            self._check_name(name, "free")
            self.fixed.pop(name, None)
        for name, value in (fixed or {}).items():
            self._check_name(name, "fixed")
            self.fixed[name] = float(value)
        self.free_names: tuple[str, ...] = tuple(
            n for n in self.parameter_names if n not in self.fixed
        )
        for name in self.free_names:  # the prior owns the support: it must be physical
            try:
                self.parameter(name).check_prior(self.priors[name])
            except ValueError as err:
                raise ModelError(str(err)) from None

    # -- naming -----------------------------------------------------------------
    def _check_name(self, name: str, what: str) -> None:
        if name not in self._index:
            raise ModelError(
                f"{what}: {name!r} is not a parameter of this model; parameters are "
                f"{', '.join(self.parameter_names)}"
            )

    def index(self, name: str) -> int:
        """Column of parameter ``name`` in a full parameter array."""
        self._check_name(name, "index")
        return self._index[name]

    def parameter(self, name: str) -> Parameter:
        """The :class:`Parameter` called ``name``."""
        return self.parameters[self.index(name)]

    def effect_slices(self) -> list[tuple[type[Effect], slice]]:
        """Each effect with the columns its parameters occupy in a full parameter array."""
        out, start = [], self._base_count
        for eff in self.effects:
            out.append((eff, slice(start, start + len(eff.parameters))))
            start += len(eff.parameters)
        return out

    @property
    def rig_columns(self) -> dict[str, int]:
        """Column of each rig value identified as a parameter (``rig_KEY``), by key."""
        return {key: self._effect_end + j for j, (key, _) in enumerate(self.rig.priors)}

    def is_rig_parameter(self, name: str) -> bool:
        """Whether ``name`` is the parameter of a rig value given as a prior."""
        return self._index.get(name, -1) >= self._effect_end

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the composed effects."""
        return tuple(e.name for e in self.effects)

    def with_effects(self, *effects: str | type[Effect] | Effect) -> Model:
        """A new model with ``effects`` appended (priors and fixings kept)."""
        return Model(
            self.effects + resolve_effects(effects),
            rig=self.rig,
            priors=self.chosen_priors(),
            fixed={n: v for n, v in self.fixed.items() if self.parameter(n).vary},
        )

    def chosen_priors(self, rig: Rig | None = None) -> dict[str, Prior]:
        """The priors that replace the parameters' own, for a model on ``rig``.

        Parameters
        ----------
        rig : Rig, optional
            Where the priors go; this model's rig by default. A rig value's prior
            (``rig_KEY``) is kept only where ``rig`` identifies that value too.

        Returns
        -------
        dict
        """
        rig = self.rig if rig is None else rig
        keys = {f"{RIG_PREFIX}{k}" for k, _ in rig.priors}
        return {n: p for n, p in self.priors.items() if p is not self.parameter(n).prior
                and (not self.is_rig_parameter(n) or n in keys)}

    @classmethod
    def for_dataset(cls, dataset, effects: Iterable[str | type[Effect] | Effect] | str = (),
                    *, priors: Mapping[str, Prior] | None = None,
                    fixed: Mapping[str, float] | None = None) -> Model:
        """The model for a data set, on the rig its metadata records.

        Parameters
        ----------
        dataset : Dataset
            Data whose ``metadata["rig"]`` (if any) gives the rig; the
            characterisation rig otherwise, said once per file
            (:func:`assumed_rig`).
        effects : iterable or str
            Effects to add to the base model.
        priors : mapping of str to Prior, optional
            Overrides of the default priors.
        fixed : mapping of str to float, optional
            Parameters held fixed.

        Returns
        -------
        Model
        """
        rig = _rig_of(dataset)
        if rig is None:
            assumed_rig(dataset)
            rig = Rig.characterisation()
        return cls(effects, rig=rig, priors=priors, fixed=fixed)

    def on_rig(self, where: Rig | object) -> Model:
        """This model (effects, priors, fixed values) on another rig: a :class:`Rig`, or the
        rig a data set records.

        Parameters
        ----------
        where : Rig or Dataset
            The rig, or data whose ``metadata["rig"]`` (if any) gives it.

        Returns
        -------
        Model
            This model itself where the data set records no rig or the rig is this
            model's; otherwise a model with the same effects, free parameters, fixed
            values and the priors this one replaced, on the other rig.

        Raises
        ------
        ModelError
            If the recorded rig is not valid (the message names the data's file).
        """
        rig = where if isinstance(where, Rig) else _rig_of(where)
        if rig is None or rig == self.rig:
            return self
        return Model(self.effects, rig=rig, priors=self.chosen_priors(rig),
                     fixed=dict(self.fixed),
                     free=[n for n in self.free_names if not self.is_rig_parameter(n)])

    def with_default_priors(self, priors: Mapping[str, Prior]) -> Model:
        """This model with other default priors where its priors are still the defaults.

        A prior the user chose (one that replaced the parameter's own) wins.

        Parameters
        ----------
        priors : mapping of str to Prior
            New defaults, by parameter name (names the model lacks are skipped).

        Returns
        -------
        Model
        """
        chosen = self.chosen_priors()
        new = {n: p for n, p in priors.items() if n in self._index and n not in chosen}
        if not new:
            return self
        return Model(self.effects, rig=self.rig, priors={**new, **chosen},
                     fixed=dict(self.fixed),
                     free=[n for n in self.free_names if not self.is_rig_parameter(n)])

    # -- parameter arrays -------------------------------------------------------
    @property
    def defaults(self) -> dict[str, float]:
        """Default value of every parameter (fixed ones at their fixed value)."""
        d = {p.name: p.default for p in self.parameters}
        d.update(self.fixed)
        return d

    def theta(
        self, params: Mapping[str, float | np.ndarray] | np.ndarray | None = None
    ) -> np.ndarray:
        """A full ``(batch, n_parameters)`` parameter array.

        Parameters
        ----------
        params : mapping or array, optional
            A mapping from names to scalars or 1-D arrays (one value per batch
            member); missing names take their default. Or an array of shape
            ``(n_parameters,)`` or ``(batch, n_parameters)`` in
            :attr:`parameter_names` order. None gives the defaults.

        Returns
        -------
        numpy.ndarray
            C-contiguous float64 array ``(batch, n_parameters)``.

        Raises
        ------
        ModelError
            On unknown names, inconsistent batch sizes, wrong shapes, or values
            outside a parameter's bounds.
        """
        if params is None:
            params = {}
        if isinstance(params, Mapping):
            for name in params:
                self._check_name(name, "parameters")
            sizes = {np.size(v) for v in params.values() if np.ndim(v) > 0}
            if len(sizes) > 1:
                raise ModelError(f"parameter arrays have different lengths {sorted(sizes)}")
            batch = sizes.pop() if sizes else 1
            defaults = self.defaults
            theta = np.empty((batch, len(self.parameter_names)))
            for j, name in enumerate(self.parameter_names):
                value = np.asarray(params.get(name, defaults[name]), dtype=float)
                if value.ndim > 1:
                    raise ModelError(f"parameter {name!r} must be a scalar or 1-D array")
                theta[:, j] = value
        else:
            theta = np.array(params, dtype=float, ndmin=2)
            if theta.ndim != 2 or theta.shape[1] != len(self.parameter_names):
                raise ModelError(
                    f"parameter array of shape {np.shape(params)} does not match the model's "
                    f"{len(self.parameter_names)} parameters {self.parameter_names}"
                )
            theta = np.ascontiguousarray(theta)
        self.check_bounds(theta)
        return theta

    def check_bounds(self, theta: np.ndarray) -> None:
        """Raise :class:`ModelError` naming the first parameter outside its bounds."""
        for j, p in enumerate(self.parameters):
            bad = ~p.in_bounds(theta[:, j])
            if bad.any():
                i = int(np.argmax(bad))
                raise ModelError(
                    f"parameter {p.name} = {float(theta[i, j])!r} (batch member {i}) is "
                    f"outside its bounds {p.bounds} [{p.unit}]"
                )

    def describe(self) -> list[dict]:
        """One row per parameter: name, unit, default, prior, bounds, fixed, meaning, source."""
        rows = []
        owners = ["base"] * self._base_count + [
            e.name for e in self.effects for _ in e.parameters
        ] + ["rig"] * len(self.rig.priors)
        for p, owner in zip(self.parameters, owners, strict=True):
            rows.append(
                {
                    "name": p.name,
                    "unit": p.unit,
                    "default": self.defaults[p.name],
                    "prior": str(self.priors[p.name]),
                    "bounds": p.bounds,
                    "fixed": p.name in self.fixed,
                    "description": p.description,
                    "source": owner,
                }
            )
        return rows

    def __repr__(self) -> str:
        eff = ", ".join(self.effect_names) or "none"
        return f"Model(rig={self.rig.name}, effects={eff}, parameters={len(self.parameters)})"


def _rig_of(dataset) -> Rig | None:
    """The rig a data set's metadata records, or None where it records none."""
    rig_meta = declared_rig(dataset.metadata)  # checked against the schema on reading
    if rig_meta is None:
        return None
    try:
        return Rig.from_dict(rig_meta)
    except ModelError as err:  # name the file: the rig comes from its sidecar
        raise ModelError(f"{dataset.source or 'data set'}: metadata 'rig': {err}") from None
