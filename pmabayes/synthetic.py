"""Synthetic repeated-chirp data, like the paper's characterisation runs.

Everything here is synthetic: the positions come from :func:`pmabayes.simulate`
of a chosen model, with optional *hidden effects* the fitted model may lack, plus
a realistic measurement: a trial-to-trial disturbance that is autocorrelated in
time and the quantisation of the paper's encoder (2000 counts per inch). The
generator's settings are recorded in the dataset's metadata (the JSON sidecar),
so every file says how to make it again.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass

import numpy as np

from pmabayes.data import DataError, Dataset
from pmabayes.inference.likelihood import ar1_noise
from pmabayes.model.effects import Effect, get_effect
from pmabayes.model.model import ENCODER_COUNTS_PER_M, Model, ModelError, Rig
from pmabayes.model.parameters import HalfNormal, Parameter
from pmabayes.model.simulator import simulate

__all__ = [
    "ENCODER_COUNTS_PER_M",
    "PLAUSIBLE_REGION",
    "draw_plausible",
    "Chirp",
    "MeasurementNoise",
    "Regulator",
    "hidden_effects_model",
    "generate_chirp_dataset",
    "example_data",
    "example_fit",
    "HiddenDetent",
    "HiddenDrag",
    "HiddenCompressionSpring",
    "HiddenZForce",
    "OUTSIDE_LIBRARY",
]

#: Where a PMA like the paper's plausibly lies: ``(low, high, scale)`` per base
#: parameter, drawn uniformly (``"log"``: log-uniformly) by :func:`draw_plausible`.
#: The priors are wider; this region is for simulation studies (calibration,
#: detection rates) that need realistic muscles, not degenerate ones.
#:
#: :meta hide-value:
PLAUSIBLE_REGION: dict[str, tuple[float, float, str]] = {
    "alpha": (12.0, 45.0, "log"),
    "beta": (0.5, 5.0, "log"),
    "gamma": (-60.0, -25.0, "linear"),
    "d": (100.0, 240.0, "log"),
    "K_e": (450.0, 850.0, "log"),
    "p_dz": (40e3, 100e3, "linear"),
}


def draw_plausible(rng: np.random.Generator) -> dict[str, float]:
    """Draw base-model parameters from :data:`PLAUSIBLE_REGION`.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.

    Returns
    -------
    dict
        One value per base parameter.

    Examples
    --------
    >>> import numpy as np
    >>> from pmabayes.synthetic import draw_plausible
    >>> values = draw_plausible(np.random.default_rng(0))
    >>> sorted(values)
    ['K_e', 'alpha', 'beta', 'd', 'gamma', 'p_dz']
    >>> bool(450.0 <= values["K_e"] <= 850.0)
    True
    """
    out = {}
    for name, (lo, hi, scale) in PLAUSIBLE_REGION.items():
        if scale == "log":
            out[name] = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        else:
            out[name] = float(rng.uniform(lo, hi))
    return out


@dataclass(frozen=True)
class Chirp:
    """A pressure chirp between two levels with linearly rising frequency.

    ``p(t) = p_min + (p_max - p_min) / 2 * (1 - cos(2 pi (f0 t + (f1 - f0) t^2 / (2 T))))``,
    which starts at rest at ``p_min``. The paper's: 0.1 to 3 Hz over 15 s, 0 to 0.5 MPa.

    Parameters
    ----------
    f0_hz, f1_hz : float
        Start and end frequency.
    duration_s : float
        Length ``T`` of the chirp.
    p_min_pa, p_max_pa : float
        Pressure range (gauge).
    sample_rate_hz : float
        Sampling rate of command and measurement.

    Examples
    --------
    >>> from pmabayes.synthetic import Chirp
    >>> chirp = Chirp(duration_s=2.0, sample_rate_hz=100.0)
    >>> chirp.time_s.size, float(chirp.pressure_pa()[0]), float(chirp.frequency_hz(2.0))
    (200, 0.0, 3.0)
    """

    f0_hz: float = 0.1
    f1_hz: float = 3.0
    duration_s: float = 15.0
    p_min_pa: float = 0.0
    p_max_pa: float = 0.5e6
    sample_rate_hz: float = 1000.0

    def __post_init__(self) -> None:
        if not (0 < self.f0_hz and 0 < self.f1_hz and self.duration_s > 0):
            raise DataError(f"chirp needs positive frequencies and duration, got {self}; "
                            "give f0_hz, f1_hz and duration_s (--duration) > 0")
        if not self.p_min_pa < self.p_max_pa:
            raise DataError(f"chirp needs p_min_pa < p_max_pa, got {self}; swap or fix them")
        if not self.sample_rate_hz > 0:
            raise DataError(f"sample_rate_hz must be > 0, got {self.sample_rate_hz}; give "
                            "the sample rate in Hz (--rate)")
        if self.time_s.size < 2:
            raise DataError(f"chirp of {self.duration_s:g} s at {self.sample_rate_hz:g} Hz has "
                            "fewer than 2 samples; lengthen it (--duration) or sample faster "
                            "(--rate)")

    @property
    def time_s(self) -> np.ndarray:
        """Sample times, ``round(duration * rate)`` samples from 0."""
        n = int(round(self.duration_s * self.sample_rate_hz))
        return np.arange(n) / self.sample_rate_hz

    def phase_cycles(self, time_s: np.ndarray) -> np.ndarray:
        """Phase of the chirp in cycles."""
        rate = (self.f1_hz - self.f0_hz) / (2.0 * self.duration_s)
        return self.f0_hz * time_s + rate * time_s**2

    def frequency_hz(self, time_s: np.ndarray) -> np.ndarray:
        """Instantaneous frequency at ``time_s``."""
        return self.f0_hz + (self.f1_hz - self.f0_hz) * np.asarray(time_s) / self.duration_s

    def pressure_pa(self, time_s: np.ndarray | None = None) -> np.ndarray:
        """The commanded pressure at ``time_s`` (default: :attr:`time_s`)."""
        t = self.time_s if time_s is None else np.asarray(time_s, dtype=float)
        half = 0.5 * (self.p_max_pa - self.p_min_pa)
        return self.p_min_pa + half * (1.0 - np.cos(2.0 * np.pi * self.phase_cycles(t)))


@dataclass(frozen=True)
class MeasurementNoise:
    """How the synthetic measurement departs from the model's position.

    Each trial gets its own disturbance ``e``, a stationary AR(1) (discretised
    Ornstein-Uhlenbeck) process with standard deviation ``disturbance_std_m`` and
    correlation time ``disturbance_corr_time_s``: it stands for what changes from
    one repetition to the next (supply pressure, temperature, the braid settling).
    A second, independent AR(1) component of another time scale
    (``slow_std_m``, ``slow_corr_time_s``) makes a disturbance of two time scales,
    which the likelihood's AR(1) + white noise model does not describe (off by
    default). The encoder then reports ``counts_per_m``-quantised ``x + e``.

    Parameters
    ----------
    disturbance_std_m : float
        Standard deviation of the per-trial disturbance; 0 turns it off.
    disturbance_corr_time_s : float
        Correlation time; the lag-one autocorrelation at sample interval ``dt`` is
        ``exp(-dt / corr_time)``.
    encoder_counts_per_m : float or None
        Encoder resolution; None for no quantisation.
    slow_std_m : float
        Standard deviation of the disturbance's second component; 0 (the default)
        for a disturbance of one time scale.
    slow_corr_time_s : float
        Correlation time of the second component.

    Examples
    --------
    A disturbance of 20 µm and no encoder: the data depart from the exact model output
    (``noise=None``) by about that much:

    >>> import numpy as np
    >>> from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset
    >>> chirp = Chirp(duration_s=4.0, sample_rate_hz=200.0)
    >>> noisy = generate_chirp_dataset(n_trials=3, chirp=chirp, seed=1,
    ...                                noise=MeasurementNoise(20e-6, encoder_counts_per_m=None))
    >>> exact = generate_chirp_dataset(n_trials=3, chirp=chirp, noise=None)
    >>> round(float(np.std(noisy.position_m - exact.position_m)) * 1e6)  # µm
    20
    """

    disturbance_std_m: float = 60e-6
    disturbance_corr_time_s: float = 0.1
    encoder_counts_per_m: float | None = ENCODER_COUNTS_PER_M
    slow_std_m: float = 0.0
    slow_corr_time_s: float = 1.0

    def __post_init__(self) -> None:
        if self.disturbance_std_m < 0:
            raise DataError(f"disturbance_std_m must be >= 0, got {self.disturbance_std_m}")
        if not self.disturbance_corr_time_s > 0:
            raise DataError(
                f"disturbance_corr_time_s must be > 0, got {self.disturbance_corr_time_s}"
            )
        if self.encoder_counts_per_m is not None and not self.encoder_counts_per_m > 0:
            raise DataError(f"encoder_counts_per_m must be > 0, got {self.encoder_counts_per_m}")
        if not self.slow_std_m >= 0:
            raise DataError(f"slow_std_m must be >= 0, got {self.slow_std_m}")
        if not self.slow_corr_time_s > 0:
            raise DataError(f"slow_corr_time_s must be > 0, got {self.slow_corr_time_s}")

    def disturbance(self, n_trials: int, n_samples: int, dt_s: float, rng: np.random.Generator):
        """Draw ``(n_trials, n_samples)`` stationary disturbances: AR(1), plus the
        second time scale's AR(1) when ``slow_std_m > 0`` (drawn after the first)."""
        phi = math.exp(-dt_s / self.disturbance_corr_time_s)
        e = ar1_noise(n_trials, n_samples, self.disturbance_std_m, phi, rng)
        if self.slow_std_m > 0:
            phi_slow = math.exp(-dt_s / self.slow_corr_time_s)
            e += ar1_noise(n_trials, n_samples, self.slow_std_m, phi_slow, rng)
        return e

    def apply(self, position_m: np.ndarray, dt_s: float, rng: np.random.Generator) -> np.ndarray:
        """Measure ``position_m`` (``(n_trials, n_samples)``): disturb, then quantise."""
        y = position_m + self.disturbance(*position_m.shape, dt_s, rng)
        if self.encoder_counts_per_m is not None:
            y = np.round(y * self.encoder_counts_per_m) / self.encoder_counts_per_m
        return y


@dataclass(frozen=True)
class Regulator:
    """A pressure regulator and its transducer: why the measured pressures of repeated
    trials differ although their command is one.

    Each trial's acting pressure is the command through a first-order lag whose time
    constant is drawn per trial, uniformly in ``[tau_min_s, tau_max_s]`` (the
    regulator's response changes a little from run to run), starting at rest at the
    first command; the transducer adds white noise of ``sensor_std_fs`` times the
    full scale ``full_scale_pa``. The model is driven by the acting pressure; the data
    set records the measured one.

    Parameters
    ----------
    tau_min_s, tau_max_s : float
        Range of the lag's time constant, s.
    sensor_std_fs : float
        Transducer noise, a fraction of the full scale (0.003: 0.3%).
    full_scale_pa : float
        The transducer's full scale, Pa.

    Examples
    --------
    Measured pressures: each trial's record differs from the command, and from the others'.

    >>> import numpy as np
    >>> from pmabayes.synthetic import Chirp, Regulator, generate_chirp_dataset
    >>> data = generate_chirp_dataset(n_trials=3, chirp=Chirp(duration_s=4.0, sample_rate_hz=200.0),
    ...                               regulator=Regulator(), seed=1)
    >>> bool(np.allclose(data.input[0], data.input[1]))
    False
    >>> data.metadata["generator"]["regulator"]["tau_max_s"]
    0.006
    """

    tau_min_s: float = 0.002
    tau_max_s: float = 0.006
    sensor_std_fs: float = 0.003
    full_scale_pa: float = 0.5e6

    def __post_init__(self) -> None:
        if not 0 < self.tau_min_s <= self.tau_max_s:
            raise DataError(f"the regulator needs 0 < tau_min_s <= tau_max_s, got {self}")
        if not (self.sensor_std_fs >= 0 and self.full_scale_pa > 0):
            raise DataError(f"the regulator needs sensor_std_fs >= 0 and full_scale_pa > 0, "
                            f"got {self}")

    def pressures(self, command_pa: np.ndarray, n_trials: int, dt_s: float,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The acting and the measured pressures, each ``(n_trials, n_samples)``.

        Parameters
        ----------
        command_pa : numpy.ndarray
            The command, ``(n_samples,)``, held between samples.
        n_trials : int
        dt_s : float
            Sample interval.
        rng : numpy.random.Generator
            Draws the time constants, then the transducer's noise.

        Returns
        -------
        acting, measured : numpy.ndarray
        """
        tau = rng.uniform(self.tau_min_s, self.tau_max_s, n_trials)
        a = np.exp(-dt_s / tau)
        acting = np.empty((n_trials, command_pa.size))
        acting[:, 0] = command_pa[0]
        for k in range(1, command_pa.size):  # exact for a command held over the step
            acting[:, k] = a * acting[:, k - 1] + (1.0 - a) * command_pa[k - 1]
        measured = acting + rng.normal(0.0, self.sensor_std_fs * self.full_scale_pa,
                                       acting.shape)
        return acting, measured


def hidden_effects_model(
    effects: Mapping[str | type[Effect], Mapping[str, float] | float] | None,
    *,
    rig: Rig | None = None,
) -> tuple[Model, dict[str, float]]:
    """A model with the given effects and the parameter values they are set to.

    Parameters
    ----------
    effects : mapping
        Effect (a registered name, or an :class:`~pmabayes.model.effects.Effect` subclass
        such as those of :data:`OUTSIDE_LIBRARY`, which no library holds) to either a
        mapping of its parameter values, or one number for its first varying parameter
        (``{"regulator_lag": 0.045}``). Parameters not given keep their defaults.
    rig : Rig, optional
        The rig; characterisation rig by default.

    Returns
    -------
    model : Model
    values : dict
        The values of every effect parameter given.

    Raises
    ------
    ModelError
        On an unknown parameter of an effect.

    Examples
    --------
    >>> from pmabayes.synthetic import hidden_effects_model
    >>> hidden_effects_model({"regulator_lag": 0.045})
    (Model(rig=characterisation, effects=regulator_lag, parameters=7), {'tau_reg': 0.045})

    The effects in no library are hidden the same way; the generator records them, and
    a fitted model does not know them:

    >>> from pmabayes.synthetic import (Chirp, HiddenCompressionSpring, HiddenDetent,
    ...                                 HiddenDrag, HiddenZForce, generate_chirp_dataset)
    >>> hidden = {HiddenDetent: 2.0, HiddenDrag: 300.0, HiddenCompressionSpring: 800.0,
    ...           HiddenZForce: 0.005}
    >>> data = generate_chirp_dataset(n_trials=2, chirp=Chirp(duration_s=2.0, sample_rate_hz=200.0),
    ...                               effects=hidden, seed=1)
    >>> for name, values in data.metadata["generator"]["effects"].items():
    ...     print(name, values)
    hidden_detent {'F_det': 2.0}
    hidden_drag {'c_hidden': 300.0}
    hidden_compression_spring {'k_cs': 800.0}
    hidden_z_force {'c_hz': 0.005}
    """
    effects = dict(effects or {})
    model = Model(list(effects), rig=rig)
    values: dict[str, float] = {}
    for key, setting in effects.items():
        eff = get_effect(key) if isinstance(key, str) else key
        if isinstance(setting, Mapping):
            for pname, value in setting.items():
                if pname not in eff.parameter_names():
                    raise ModelError(
                        f"effect {eff.name!r} has no parameter {pname!r}; it has "
                        f"{', '.join(eff.parameter_names())}"
                    )
                values[pname] = float(value)
        else:
            first = next(p.name for p in eff.parameters if p.vary)
            values[first] = float(setting)
    return model, values


def generate_chirp_dataset(
    *,
    n_trials: int = 10,
    seed: int | None = 0,
    rng: np.random.Generator | None = None,
    chirp: Chirp | None = None,
    noise: MeasurementNoise | None = MeasurementNoise(),
    params: Mapping[str, float] | None = None,
    effects: Mapping[str | type[Effect], Mapping[str, float] | float] | None = None,
    rig: Rig | None = None,
    description: str = "",
    regulator: Regulator | None = None,
) -> Dataset:
    """Repeated chirp trials from a model with optional hidden effects.

    Parameters
    ----------
    n_trials : int
        Number of repeated trials (all share the commanded pressure).
    seed : int or None
        Seed of the noise; ignored when ``rng`` is given.
    rng : numpy.random.Generator, optional
        Generator to draw the noise from (its state is not recorded).
    chirp : Chirp, optional
        The commanded pressure; the paper's chirp by default.
    noise : MeasurementNoise or None
        The measurement; None gives the exact model output.
    params : mapping, optional
        Base-model parameter values; the paper's by default.
    effects : mapping, optional
        Hidden effects and their values, as for :func:`hidden_effects_model`.
    rig : Rig, optional
        The rig; characterisation rig by default.
    description : str
        Free text stored in the metadata.
    regulator : Regulator, optional
        Measured inputs: each trial is driven by the command through the regulator,
        and records the measured pressure (its own per trial; drawn before the
        measurement noise). None (the default): every trial records the command.

    Returns
    -------
    Dataset
        With metadata ``synthetic=True`` and the full generator settings.

    Examples
    --------
    Three short chirps (4 s at 200 Hz) from the paper's model with a 45 ms regulator lag
    it lacks, reproducible from the seed:

    >>> from pmabayes.synthetic import Chirp, generate_chirp_dataset
    >>> data = generate_chirp_dataset(n_trials=3, chirp=Chirp(duration_s=4.0, sample_rate_hz=200.0),
    ...                               effects={"regulator_lag": 0.045}, seed=1)
    >>> data
    Dataset(n_trials=3, n_samples=800, dt_s=0.005, input_name='pressure_pa', trial_ids=[0, 1, 2],
            source=None)
    >>> data.metadata["synthetic"], data.metadata["generator"]["effects"]
    (True, {'regulator_lag': {'tau_reg': 0.045}})

    ``pmabayes.data.save(data, "lagged.csv")`` writes it, with a sidecar that records
    every setting.
    """
    if not (isinstance(n_trials, int | np.integer) and n_trials >= 1):
        raise DataError(f"n_trials must be a positive integer, got {n_trials!r}; give 2 or more "
                        "repeated trials (--trials) to fit the data")
    chirp = Chirp() if chirp is None else chirp
    model, effect_values = hidden_effects_model(effects, rig=rig)
    values = dict(model.defaults)
    for name, value in (params or {}).items():
        model.index(name)  # raises on unknown names
        values[name] = float(value)
    values.update(effect_values)
    time_s = chirp.time_s
    dt = 1.0 / chirp.sample_rate_hz
    pressure = chirp.pressure_pa(time_s)
    if rng is None:
        rng = np.random.default_rng(seed)
        recorded_seed = seed
    else:
        recorded_seed = None
    if regulator is None:
        x = simulate(model, values, pressure, time_s=time_s)[0]
        inputs = np.repeat(pressure[None], n_trials, axis=0)
    else:  # each trial driven by its own acting pressure, which it records as measured
        acting, inputs = regulator.pressures(pressure, n_trials, dt, rng)
        x = simulate(model, model.theta(values)[np.zeros(n_trials, dtype=int)], acting,
                     time_s=time_s)
    trials_x = np.repeat(x[None], n_trials, axis=0) if x.ndim == 1 else x
    position = trials_x if noise is None else noise.apply(trials_x, dt, rng)
    metadata = {
        "synthetic": True,
        "description": description
        or "Synthetic repeated pressure-chirp trials generated by pmabayes (not measured).",
        "sample_rate_hz": chirp.sample_rate_hz,
        "rig": model.rig.to_dict(),
        "generator": {
            "function": "pmabayes.synthetic.generate_chirp_dataset",
            "seed": recorded_seed,
            "n_trials": int(n_trials),
            "chirp": asdict(chirp),
            "noise": None if noise is None else asdict(noise),
            "effects": {eff.name: {p: effect_values[p] for p in eff.parameter_names()
                                   if p in effect_values} for eff in model.effects},
            "parameters": {k: float(v) for k, v in values.items()},
        },
    }
    if regulator is not None:
        metadata["generator"]["regulator"] = asdict(regulator)
    return Dataset(
        time_s=time_s,
        input=inputs,
        position_m=position,
        trial_ids=np.arange(n_trials),
        input_name=model.rig.input_name,
        metadata=metadata,
    )


def example_data(seed: int = 1) -> Dataset:
    """The small synthetic data set of the examples: three 4 s chirp trials at 200 Hz.

    Parameters
    ----------
    seed : int
        The generator's seed.

    Returns
    -------
    Dataset
        :func:`generate_chirp_dataset` of the paper's model, 800 samples a trial.

    Examples
    --------
    >>> from pmabayes.synthetic import example_data
    >>> example_data()
    Dataset(n_trials=3, n_samples=800, dt_s=0.005, input_name='pressure_pa', trial_ids=[0, 1, 2],
            source=None)
    """
    return generate_chirp_dataset(n_trials=3, seed=seed,
                                  chirp=Chirp(duration_s=4.0, sample_rate_hz=200.0))


@functools.cache
def _example_fit(seed: int):
    from pmabayes.inference.sampler import FitSettings, fit

    # 50 steps of 16 walkers: seconds, not a converged posterior
    return fit(example_data(seed), settings=FitSettings(n_walkers=16, n_ensembles=1,
                                                        max_steps=50))


def example_fit(seed: int = 1):
    """A short fit of :func:`example_data`, for examples of what takes a fit.

    Like ArviZ's example data sets, one call serves every example; the fit is made once
    a process and each call returns its own copy. It is too short to converge (50 steps
    of 16 walkers), and it warns so the first time.

    Parameters
    ----------
    seed : int
        The seed of the data (and of the sampler, through :func:`pmabayes.fit`'s
        default).

    Returns
    -------
    xarray.DataTree
        The fit file's tree, as :func:`pmabayes.fit` returns it.

    Examples
    --------
    >>> from pmabayes.synthetic import example_fit
    >>> tree = example_fit()  # warns: not converged
    >>> sorted(tree["posterior"].data_vars)[:3]
    ['K_e', 'alpha', 'beta']
    """
    return _example_fit(int(seed)).copy(deep=True)


# ---------------------------------------------------------------------------------
# Effects in no library: the stand-ins for physics pmabayes does not know, used to
# hide an unknown effect in synthetic data (the discrepancy step's tests and studies).
# They are never registered, so `diagnose` never offers them as candidates.


def _detent(q, x, v, p):
    k = 2.0 * np.pi / q[1]
    return q[0] * np.sin(k * x), q[0] * k * np.cos(k * x), 0.0  # force, d/dx, d/dv


class HiddenDetent(Effect):
    """A rail's detent force, periodic in position (in no library).

    Hidden in synthetic data by :func:`generate_chirp_dataset` (see
    :func:`hidden_effects_model`'s example); a fitted model does not know it.

    Examples
    --------
    A quarter of a period in, the detent pushes with its full amplitude:

    >>> import numpy as np
    >>> from pmabayes.synthetic import HiddenDetent
    >>> force_n, _, _ = HiddenDetent.force_n(np.array([2.0, 0.01]), 0.0025, 0.0, 0.0)
    >>> round(force_n, 9)
    2.0
    """

    __test__ = False  # not a pytest class
    name = "hidden_detent"
    stage = "force"
    parameters = (
        Parameter("F_det", "N", 1.0, HalfNormal(5.0), bounds=(0.0, math.inf), null=0.0,
                  description="detent amplitude"),
        Parameter("L_det", "m", 0.01, HalfNormal(0.05), bounds=(0.0, math.inf), null=0.01,
                  vary=False, description="detent period"),
    )
    description = "Detent force of a rail, periodic in position (hidden; synthetic data)."
    physics = staticmethod(_detent)


def _drag(q, x, v, p):
    return q[0] * v * abs(v), 0.0, 2.0 * q[0] * abs(v)


class HiddenDrag(Effect):
    """A quadratic drag, ``c_hidden v |v|`` (in no library).

    Hidden in synthetic data by :func:`generate_chirp_dataset` (see
    :func:`hidden_effects_model`'s example); a fitted model does not know it.

    Examples
    --------
    >>> import numpy as np
    >>> from pmabayes.synthetic import HiddenDrag
    >>> round(HiddenDrag.force_n(np.array([300.0]), 0.0, 0.1, 0.0)[0], 9)  # N at 0.1 m/s
    3.0
    """

    __test__ = False
    name = "hidden_drag"
    stage = "force"
    parameters = (
        Parameter("c_hidden", "N s^2/m^2", 0.0, HalfNormal(500.0), bounds=(0.0, math.inf),
                  null=0.0, description="drag force per squared velocity"),
    )
    description = "Drag growing with the square of the velocity (hidden; synthetic data)."
    physics = staticmethod(_drag)


def _compression(q, x, v, p):
    if x < q[1]:
        return q[0] * (x - q[1]), q[0], 0.0
    return 0.0, 0.0, 0.0


class HiddenCompressionSpring(Effect):
    """A spring acting only below ``x_cs``, in compression (in no library).

    Hidden in synthetic data by :func:`generate_chirp_dataset` (see
    :func:`hidden_effects_model`'s example); a fitted model does not know it.

    Examples
    --------
    1 mm below ``x_cs`` it pushes back; above, it is slack:

    >>> import numpy as np
    >>> from pmabayes.synthetic import HiddenCompressionSpring
    >>> q = np.array([800.0, 0.005])
    >>> [round(HiddenCompressionSpring.force_n(q, x, 0.0, 0.0)[0], 9) for x in (0.004, 0.01)]
    [-0.8, 0.0]
    """

    __test__ = False
    name = "hidden_compression_spring"
    stage = "force"
    parameters = (
        Parameter("k_cs", "N/m", 0.0, HalfNormal(1e3), bounds=(0.0, math.inf), null=0.0,
                  description="stiffness in compression"),
        Parameter("x_cs", "m", 0.005, HalfNormal(0.05), bounds=(0.0, math.inf), null=0.005,
                  vary=False, description="where it engages"),
    )
    description = "A spring stiffening the muscle in compression only (hidden; synthetic data)."
    physics = staticmethod(_compression)


def _z_force(q, x, v, p, z, s):
    return q[0] * z * abs(z), 0.0, 0.0, 2.0 * q[0] * abs(z), 0.0


class HiddenZForce(Effect):
    """A hysteretic force growing as ``z |z|``: a loop that fattens faster than z.

    Hidden in synthetic data by :func:`generate_chirp_dataset` (see
    :func:`hidden_effects_model`'s example); a fitted model does not know it.

    Examples
    --------
    >>> import numpy as np
    >>> from pmabayes.synthetic import HiddenZForce
    >>> HiddenZForce.force_n(np.array([0.005]), 0.0, 0.0, 0.0, z_n=100.0)[0]  # N at z = 100 N
    50.0
    """

    __test__ = False
    name = "hidden_z_force"
    stage = "force"
    reads_z = True
    parameters = (Parameter("c_hz", "1/N", 0.0, HalfNormal(0.01), bounds=(0.0, math.inf),
                            null=0.0, description="z|z| coefficient"),)
    description = "A force in z|z| (hidden; synthetic data)."
    physics = staticmethod(_z_force)


#: The effects in no library, for hiding unknown physics in synthetic data.
#:
#: :meta hide-value:
OUTSIDE_LIBRARY: tuple[type[Effect], ...] = (HiddenDetent, HiddenDrag,
                                             HiddenCompressionSpring, HiddenZForce)
