"""Closed-loop position control of the PMA: PID and computed torque, as in the paper.

The paper's rig (section IV): the identified plant on :meth:`Rig.control
<pmabayes.model.model.Rig.control>` (a 500 g load) integrated at 1 kHz by the
simulator's own generated code, a controller at 100 Hz on the encoder reading, and
its output held at 20 Hz as the regulator's command. The reference's mean comes from
a rule (:func:`operating_mean_m`), the gains from another (:func:`tune_gains`). The
documentation's page "The closed loop" (``docs/theory/control.rst``) gives the
controllers, the operating point and the gain rule.

The modules: :mod:`~pmabayes.control.operating` (the reference and the pressure it
needs), :mod:`~pmabayes.control.kernel` (the generated closed loop),
:mod:`~pmabayes.control.metrics` and :mod:`~pmabayes.control.gains` (the rule and
its cache); this package re-exports their public names.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from pmabayes.control.gains import (
    GainGridWarning,
    nominal_gains,
    resolve_gains,
    tune_gains,
)
from pmabayes.control.gains import _delayed_plant as _delayed_plant  # for tests
from pmabayes.control.gains import _neighbours_pass as _neighbours_pass  # for tests
from pmabayes.control.kernel import (
    _GAIN_NAMES,
    CONTROLLERS,
    DEFAULT_GAINS,
    ClosedLoop,
    Timing,
    _controller_codes,
    closed_loop,
    closed_loop_batch,
    gain_array,
)
from pmabayes.control.metrics import (
    METRICS,
    command_fractions,
    loop_metrics,
    minimum_duration_s,
    period_difference_m,
    tracking_metrics,
)
from pmabayes.control.operating import (
    PAPER_REFERENCE_MEAN_M,
    REFERENCE_AMPLITUDE_M,
    ControlError,
    _check_frequency,
    _nominal_model,
    _reference_mean,
    _theta1,
    inverse_model_pressure_pa,
    operating_mean_m,
    reference_m,
)
from pmabayes.model.model import Model

__all__ = [
    "CONTROLLERS",
    "METRICS",
    "PAPER_REFERENCE_MEAN_M",
    "REFERENCE_AMPLITUDE_M",
    "REFERENCE_MEAN_M",
    "DEFAULT_GAINS",
    "ControlError",
    "GainGridWarning",
    "Timing",
    "ClosedLoop",
    "operating_mean_m",
    "inverse_model_pressure_pa",
    "reference_m",
    "closed_loop",
    "closed_loop_batch",
    "tracking_metrics",
    "command_fractions",
    "gain_array",
    "period_difference_m",
    "loop_metrics",
    "minimum_duration_s",
    "tune_gains",
    "nominal_gains",
    "resolve_gains",
    "track",
]
def __getattr__(name: str):
    # REFERENCE_MEAN_M runs the operating-point rule: on first use, not at import
    if name == "REFERENCE_MEAN_M":
        return _reference_mean()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def track(frequency_hz: float, *, controllers: Sequence[str] = CONTROLLERS,
          model: Model | None = None, params=None, duration_s: float = 10.0,
          gains: Mapping[str, Mapping[str, float]] | None = None,
          reference_mean_m: float | None = None) -> dict:
    """Metrics of each controller tracking one frequency (``pmabayes track``).

    Parameters
    ----------
    frequency_hz : float
        Reference frequency, > 0.
    controllers : sequence of str
        Which controllers to run.
    model : Model, optional
        Plant and controller model; the base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters; the paper's values by default.
    duration_s : float
        Length of each run.
    gains : mapping, optional
        Gains per controller, in full or in part; the rest by :func:`nominal_gains` on
        the model (:func:`resolve_gains`; :data:`DEFAULT_GAINS` for the paper's values).
    reference_mean_m : float, optional
        Mean of the reference; by default :func:`operating_mean_m` on the model
        (0.100 m, :data:`REFERENCE_MEAN_M`, for the paper's values).

    Returns
    -------
    dict
        ``{"frequency_hz": f, "reference_mean_m": mean, "controllers": {name:
        {"rms_error_m": ..., "max_error_m": ..., "amplitude_ratio": ...,
        "phase_lag_deg": ..., "overshoot_pct": ..., "dead_zone_fraction": ...,
        "saturated_fraction": ..., "period_difference_m": ...}}, "gains": {...}}``,
        the gains being those the runs used.

    Examples
    --------
    Both controllers following 1 Hz on the paper's model, with the paper's gains:

    >>> from pmabayes.control import track
    >>> result = track(1.0)
    >>> result["reference_mean_m"]
    0.1
    >>> {name: round(m["rms_error_m"] * 1e3, 1) for name, m in result["controllers"].items()}
    {'pid': 9.4, 'ct': 5.2}
    """
    frequency_hz = _check_frequency(frequency_hz)
    model = _nominal_model(model)
    theta = _theta1(model, params)
    names = tuple(controllers)
    _controller_codes(names, len(names))
    if reference_mean_m is None:
        reference_mean_m = operating_mean_m(model, theta)
    used = resolve_gains(names, gains, model=model, params=theta,
                         reference_mean_m=reference_mean_m)
    run = closed_loop_batch(model, np.repeat(theta, len(names), axis=0), model,
                            np.repeat(theta, len(names), axis=0),
                            np.full(len(names), frequency_hz), names,
                            duration_s=duration_s, gains=gain_array(names, used),
                            reference_mean_m=reference_mean_m, record=False)
    m = loop_metrics(run)
    rows = run.metadata["gains"]
    return {"frequency_hz": frequency_hz, "reference_mean_m": float(reference_mean_m),
            "controllers": {c: {k: float(v[j]) for k, v in m.items()}
                            for j, c in enumerate(names)},
            "gains": {c: {k: float(rows[j, i]) for i, k in enumerate(_GAIN_NAMES[c])}
                      for j, c in enumerate(names)}}
