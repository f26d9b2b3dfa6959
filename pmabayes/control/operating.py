"""The operating point of the tracking experiment: its reference and the pressure it needs.

The reference ``x_d = mean + amplitude sin(2 pi f t)`` keeps the paper's amplitude
and frequencies; its mean comes from :func:`operating_mean_m` (see
:mod:`pmabayes.control`). The inverse model here (the pressure a model needs along
``x_d``, and at rest) is shared by the gain rule, the closed loop's start and the
figures.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from pmabayes.model import boucwen
from pmabayes.model.boucwen import BoucWenColumns
from pmabayes.model.model import Model, Rig

#: The paper's reference mean, in its own (unstated) origin.
PAPER_REFERENCE_MEAN_M = 0.005
#: The paper's reference amplitude.
REFERENCE_AMPLITUDE_M = 0.0225
_PRESSURE_MAX_PA = 0.9e6


class ControlError(ValueError):
    """Bad input to a controller or a closed-loop simulation.

    Examples
    --------
    >>> from pmabayes.control import ControlError, closed_loop
    >>> try:
    ...     closed_loop("pd", 1.0)
    ... except ControlError as error:
    ...     print(error)
    unknown controller 'pd'; choose one of pid, ct
    """


def _nominal_model(model: Model | None) -> Model:
    return Model(rig=Rig.control()) if model is None else model


def _theta1(model: Model, params) -> np.ndarray:
    """One full parameter row from a mapping (model defaults for the rest) or an array."""
    theta = model.theta(params)
    if theta.shape[0] != 1:
        raise ControlError(f"one parameter set expected, got {theta.shape[0]}")
    return theta


def _inverse_pressure(model: Model | None, params, frequency_hz: float, amplitude_m: float):
    """``(pressure(mean), p_dz)``: the pressure the model needs over one period of x_d."""
    model = _nominal_model(model)
    theta = _theta1(model, params)[0]
    v = dict(zip(model.parameter_names, theta, strict=True))
    rig = model.rig
    n = 2000  # samples per period; two periods from z = 0, the second is periodic
    om = 2 * np.pi * frequency_hz
    phase = np.arange(2 * n + 1) * (2 * np.pi / n)
    s, c = np.sin(phase), np.cos(phase)
    z = boucwen.along(amplitude_m * np.diff(s), *BoucWenColumns.of(model).law(theta))
    sl = slice(n, 2 * n)
    z = z[sl]
    vel = amplitude_m * om * c[sl]
    acc = -amplitude_m * om * om * s[sl]
    p_dz = v.get("p_dz", 0.0)
    force_effects = [(e, theta[sl_e]) for e, sl_e in model.effect_slices() if e.stage == "force"]

    def pressure(mean: float) -> np.ndarray:
        x = mean + amplitude_m * s[sl]
        base = rig.moving_mass_kg * acc + v["d"] * vel + v["K_e"] * x + z + rig.gravity_force_n
        return _pressure_with_forces([q for _, q in force_effects],
                                     [e for e, _ in force_effects], np.full(x.size, p_dz),
                                     base, x, vel, rig.area_m2)

    return pressure, p_dz


def _pressure_with_forces(params: list, effects: list, p_dz: np.ndarray, base: np.ndarray,
                          x: np.ndarray, v: np.ndarray, area_m2: float) -> np.ndarray:
    """``p = p_dz + (base + f_effects(x, v, p)) / A`` per sample, by fixed point.

    ``params`` holds each force effect's parameter row: one ``(n_params,)`` row for
    all samples, or ``(n, n_params)`` rows, one per sample. An effect may depend on
    ``p``, hence the iteration (50 at most, to a relative 1e-9).
    """
    p = p_dz + base / area_m2
    for k in range(p.size if effects else 0):
        rows = [np.ascontiguousarray(q if np.ndim(q) == 1 else q[k]) for q in params]
        for _ in range(50):
            extra = sum(e.force_n(q, x[k], v[k], p[k])[0] for e, q in zip(effects, rows,
                                                                          strict=True))
            p_new = p_dz[k] + (base[k] + extra) / area_m2
            done = abs(p_new - p[k]) <= 1e-9 * (1.0 + abs(p_new))
            p[k] = p_new
            if done:
                break
    return p


def operating_mean_m(model: Model | None = None, params=None, *, frequency_hz: float = 2.0,
                     amplitude_m: float = REFERENCE_AMPLITUDE_M, margin_pa: float = 50e3,
                     pressure_max_pa: float = _PRESSURE_MAX_PA,
                     resolution_m: float = 1e-3) -> float:
    """Reference mean at which the model can follow the reference without the dead zone.

    Along ``x_d = mean + amplitude sin(2 pi f t)`` the model needs the pressure
    ``p = p_dz + (M_tot x_d'' + d x_d' + K_e x_d + z + F_g + f_effects) / A``, with
    ``z`` the Bouc-Wen force along ``x_d`` in its periodic state (rate independent,
    so it does not depend on the mean). The rule takes the smallest mean, rounded up
    to ``resolution_m``, at which ``p`` stays at least ``margin_pa`` above ``p_dz``;
    it must then also stay ``margin_pa`` under ``pressure_max_pa``.

    Parameters
    ----------
    model : Model, optional
        Model on the control rig; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters (the model's defaults, the paper's values, for those not given).
    frequency_hz : float
        The fastest reference to be tracked (the paper's 2 Hz).
    amplitude_m : float
        Reference amplitude in m.
    margin_pa : float
        Distance kept from the dead zone and from the upper limit, in Pa.
    pressure_max_pa : float
        Upper pressure limit (0.9 MPa).
    resolution_m : float
        The mean is rounded up to a multiple of this.

    Returns
    -------
    float
        The mean in m.

    Raises
    ------
    ControlError
        If no mean keeps the pressure inside both margins (lower the frequency, the
        amplitude or the margin).

    Examples
    --------
    >>> from pmabayes import Model, Rig
    >>> from pmabayes.control import operating_mean_m
    >>> operating_mean_m()  # the paper's model at 2 Hz
    0.1
    >>> operating_mean_m(Model(["regulator_lag"], rig=Rig.control()), {"tau_reg": 0.045})
    0.1
    """
    if not (frequency_hz > 0 and amplitude_m > 0 and margin_pa >= 0 and resolution_m > 0):
        raise ControlError("need frequency_hz > 0, amplitude_m > 0, margin_pa >= 0 and "
                           "resolution_m > 0")
    pressure, p_dz = _inverse_pressure(model, params, frequency_hz, amplitude_m)
    low = p_dz + margin_pa
    lo, hi = 0.0, 1.0
    if pressure(hi).min() < low:
        raise ControlError(f"no mean up to {hi} m keeps the pressure {margin_pa:g} Pa above "
                           "the dead zone")
    for _ in range(60):  # the trough's pressure grows with the mean
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pressure(mid).min() < low else (lo, mid)
    mean = math.ceil(hi / resolution_m - 1e-9) * resolution_m
    p = pressure(mean)
    if p.min() < low or p.max() > pressure_max_pa - margin_pa:
        raise ControlError(
            f"at {frequency_hz:g} Hz the model needs {p.min():.4g} to {p.max():.4g} Pa: no "
            f"mean keeps it {margin_pa:g} Pa inside p_dz..{pressure_max_pa:g} Pa; lower the "
            "frequency, the amplitude or the margin")
    return round(mean, 12)


@functools.cache
def _reference_mean() -> float:
    """:data:`REFERENCE_MEAN_M`: :func:`operating_mean_m` with the paper's values.

    Computed on first use (not at import) and kept.

    Returns
    -------
    float
        The mean in m (0.100).
    """
    return operating_mean_m()


def _mean(mean_m: float | None) -> float:
    """``mean_m``, or the reference mean for None."""
    return _reference_mean() if mean_m is None else mean_m


def __getattr__(name: str):
    if name == "REFERENCE_MEAN_M":
        return _reference_mean()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def inverse_model_pressure_pa(frequency_hz: float, *, model: Model | None = None, params=None,
                              mean_m: float | None = None,
                              amplitude_m: float = REFERENCE_AMPLITUDE_M) -> np.ndarray:
    """The pressure a model needs to follow the reference exactly, over one period.

    ``p = p_dz + (M_tot x_d'' + d x_d' + K_e x_d + z + F_g + f_effects) / A`` along
    ``x_d = mean + amplitude sin(2 pi f t)``, with ``z`` the Bouc-Wen force in its
    periodic state (the rule of :func:`operating_mean_m` keeps it inside the limits).

    Parameters
    ----------
    frequency_hz : float
        Reference frequency.
    model : Model, optional
        Model on the control rig; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters (the model's defaults for those not given).
    mean_m : float, optional
        Reference mean; :data:`REFERENCE_MEAN_M` by default.
    amplitude_m : float
        Reference amplitude.

    Returns
    -------
    numpy.ndarray
        The pressure in Pa at 2000 phases over one period, from phase 0.

    Examples
    --------
    >>> from pmabayes.control import inverse_model_pressure_pa
    >>> p_pa = inverse_model_pressure_pa(1.0)
    >>> p_pa.shape, round(float(p_pa.min()) / 1e3), round(float(p_pa.max()) / 1e3)  # kPa
    ((2000,), 207, 448)
    """
    frequency_hz = _check_frequency(frequency_hz)
    pressure, _ = _inverse_pressure(model, params, frequency_hz, amplitude_m)
    return pressure(_mean(mean_m))


def reference_m(time_s: np.ndarray, frequency_hz, *, mean_m: float | None = None,
                amplitude_m: float = REFERENCE_AMPLITUDE_M) -> np.ndarray:
    """The tracking reference ``x_d = mean + amplitude sin(2 pi f t)``.

    Parameters
    ----------
    time_s : numpy.ndarray
        Times in s.
    frequency_hz : float or numpy.ndarray
        Reference frequency (an array broadcasts against ``time_s``).
    mean_m : float, optional
        Mean, :data:`REFERENCE_MEAN_M` by default (see :func:`operating_mean_m`).
    amplitude_m : float
        Amplitude, the paper's 22.5 mm.

    Returns
    -------
    numpy.ndarray
        The reference in m.

    Examples
    --------
    >>> import numpy as np
    >>> from pmabayes.control import reference_m
    >>> reference_m(np.array([0.0, 0.25, 0.5]), 1.0)  # a quarter and half a period
    array([0.1   , 0.1225, 0.1   ])
    """
    return _mean(mean_m) + amplitude_m * np.sin(2 * np.pi * np.asarray(frequency_hz)
                                         * np.asarray(time_s))


def _check_frequency(frequency_hz) -> float:
    if isinstance(frequency_hz, bool) or not isinstance(frequency_hz, int | float | np.number):
        raise ControlError(f"frequency must be a number > 0 Hz, got {frequency_hz!r}")
    if not (math.isfinite(float(frequency_hz)) and frequency_hz > 0):
        raise ControlError(f"frequency must be > 0 Hz, got {frequency_hz}")
    return float(frequency_hz)


def _value(model: Model, theta: np.ndarray, name: str, default: float = 0.0) -> np.ndarray:
    if name in model.parameter_names:
        return theta[:, model.index(name)]
    return np.full(theta.shape[0], default)


def _initial_pressure(model: Model, theta: np.ndarray, x_m: float) -> np.ndarray:
    """Pressure holding ``model`` at rest at ``x_m`` with ``z = 0``."""
    rig = model.rig
    base = rig.gravity_force_n + theta[:, BoucWenColumns.of(model).k_e] * x_m
    force = [(e, s) for e, s in model.effect_slices() if e.stage == "force"]
    n = theta.shape[0]
    return _pressure_with_forces([theta[:, s] for _, s in force], [e for e, _ in force],
                                 np.array(_value(model, theta, "p_dz"), dtype=float), base,
                                 np.full(n, float(x_m)), np.zeros(n), rig.area_m2)
