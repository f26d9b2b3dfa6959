"""Closed-loop position control of the PMA: PID and computed torque, as in the paper.

The paper (Godage et al., section IV) tracks ``x_d = 0.005 + 0.0225 sin(2 pi f t)`` m
with a 500 g load hanging so that gravity pulls toward extension, a joint-space PID
and a computed-torque controller built on the identified Bouc-Wen model. This package
simulates that rig as faithfully as the paper describes it:

* **Plant**: the identified model (any composition of effects) on
  :meth:`Rig.control`, integrated at 1 kHz by exactly the scheme and the same
  generated code as :func:`pmabayes.simulate` (``pmabayes.model.simulator.PlantCode``),
  so replaying the closed loop's pressure command open loop reproduces its position.
* **Controller**: runs at 100 Hz on the encoder reading (quantised to the paper's
  2000 counts per inch, after the plant's measurement effects).
* **Regulator command**: the controller output is sampled at 20 Hz and held
  (zero-order hold), limited to 0..0.9 MPa (the regulator's 0-10 V range). The
  controller's output at a 20 Hz instant is applied at once (no computation delay).
* **Start**: the plant rests at the static equilibrium (``z = 0``) under the
  pressure that the controller's model needs at the reference's mean; the
  integrator of the PID starts there too (bumpless start).

**Operating point** (an assumption: the paper gives no origin for ``x``). The paper
only says that the 5 mm bias of its reference compensates the load's offset, so its
``x`` is measured from an origin it does not state. Ours is the unloaded length, and
the reference keeps the paper's amplitude (22.5 mm) and frequencies with a mean
chosen by a dynamic rule, :func:`operating_mean_m`: the smallest mean, on a 1 mm
grid, at which the pressure the nominal model needs along ``x_d`` at 2 Hz (the
paper's fastest; inertia, damping, stiffness, hysteresis, gravity, dead zone) stays
50 kPa above the dead zone ``p_dz`` and 50 kPa under 0.9 MPa. With the paper's
values this is :data:`REFERENCE_MEAN_M` = 0.100 m (77.5 to 122.5 mm; the model asks
0.118 to 0.538 MPa at 2 Hz), computed on first use. A mean closer to the sag under
the load would put the trough in the dead zone, where the actuator has no authority
and the controllers' verdicts would be set by the choice of mean. The same mean is
used by every run here unless ``reference_mean_m`` says otherwise.

**PID** (joint space, on the error ``e = x_d - y``)::

    u = K_p e + K_i int(e) + K_d (x_d' - v_hat)

``v_hat`` is the backward difference of the reading filtered by a first-order
filter of time constant ``derivative_filter_s`` (10 ms). The integrator stops while
the output saturates (clamping anti-windup).

**Computed torque** inverts the controller's model::

    F = (M + m) a + d v_hat + K_e x_hat + z_hat + (M + m) g s_g + f_effects(x_hat, v_hat, p)
    a = x_d'' + K_d (x_d' - v_hat) + K_p (x_d - x_hat)
    u = p_dz + F / A

so that for an exact model the error obeys ``e'' + K_d e' + K_p e = 0`` (the outer
error dynamics, with their own gains). ``z_hat`` comes from a Bouc-Wen observer
driven by the reading: ``z`` is rate independent, so the exact update of the
simulator is applied to each 10 ms increment of the reading. The dead zone is
inverted by adding ``p_dz``; a negative force asks for a pressure below ``p_dz``,
which vents faster. Effects of the controller's model are inverted where they say
how (the hooks of :class:`pmabayes.model.effects.Effect`; no effect is known here by name):

* force effects (friction, cubic or pressure stiffness) are added to ``F``;
* the zero-order hold (mean delay half the command period) and the pressure
  effects are inverted by prediction: the reference and the position are evaluated
  ``t_pred = T_cmd / 2 + sum of the leads`` ahead (``x_hat = y + v_hat t_pred``),
  each pressure effect's lead from its :meth:`~pmabayes.model.effects.Effect.lead_s`
  (a transport delay's dead time: exact in phase; a regulator lag's time constant:
  the first-order lead ``1 + tau s ~ exp(tau s)``, right in phase at low frequency
  and without the lead's high-frequency gain; 0 for an effect that gives none);
* measurement effects with an ``inverse`` (a sensor's zero offset, for one) are
  unwound from the reading, the last effect's first, and the reading's increments
  scaled by the inverse's slope; the others are not inverted. PID reads the
  sensor as it is.

The velocity is not predicted: ``d v_hat`` and the outer ``K_d`` term use the
filtered velocity of the reading, not the velocity ``t_pred`` ahead (a predicted
velocity needs the acceleration, which differencing a 12.7 um encoder at 100 Hz
gives too noisily).

**Gains** come from one rule, :func:`tune_gains`, run on the nominal model of the
experiment (the paper's values here, :data:`DEFAULT_GAINS`; a fit's posterior mean
in :func:`nominal_gains`): the gain set with the smallest RMS error at 0.5 Hz on a
log grid, among those that are robustly stable: with every gain doubled (a 6 dB gain
margin), and separately with an extra 20 ms delay in the plant (a delay margin:
added by the plant's effect that can absorb a delay,
:meth:`~pmabayes.model.effects.Effect.add_delay`, or by
:func:`pmabayes.model.effects.delay_effect` when it has none), the loop must still reach a
periodic steady state (the last two periods within 0.5 mm of each other) with an RMS
error at most twice the nominal; and so must its neighbours on the grid, so that the
choice is not on the knife edge of the stable set. Computed torque's natural
frequency is capped at ``pi / (2 T_cmd)`` (31.4 rad/s), half the 20 Hz hold's
Nyquist frequency (see :func:`tune_gains`). ``tests/test_control.py`` checks that
the rule reproduces :data:`DEFAULT_GAINS`. With a fit, the operating point
(:func:`operating_mean_m`) and the gains are those of the rule on the fit's nominal
model (:func:`resolve_gains`).

**Metrics** (:func:`tracking_metrics`, :func:`loop_metrics`) use whole periods after
the start-up: the first ``max(2 s, one period)`` is dropped and the largest whole
number of periods that ends at the end of the run is kept. :func:`loop_metrics`
adds the fraction of that time the command sits in the plant's dead zone (no
actuator force) or at the upper pressure limit.

**Modules**: :mod:`~pmabayes.control.operating` (the reference and the pressure it
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
