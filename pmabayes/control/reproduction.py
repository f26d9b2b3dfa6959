"""The paper's Fig. 5 reproduced in simulation, and a verdict on each of its claims.

Stage 7 (control), beside :mod:`pmabayes.control` and :mod:`pmabayes.control.robustness`:
:func:`figure5` runs PID and computed torque at 0.5, 1 and 2 Hz and checks the
paper's three claims against the metrics; the figure itself is
:func:`pmabayes.report.figures.plot_figure5`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from pmabayes.control import (
    CONTROLLERS,
    closed_loop_batch,
    gain_array,
    loop_metrics,
    operating_mean_m,
    resolve_gains,
)
from pmabayes.model.model import Model, Rig

__all__ = ["PAPER_FREQUENCIES_HZ", "figure5", "paper_claims"]

#: The frequencies of the paper's Fig. 5 panels.
PAPER_FREQUENCIES_HZ = (0.5, 1.0, 2.0)


def paper_claims(metrics: Mapping[float, Mapping[str, Mapping[str, float]]], *,
                 settle_tolerance_m: float = 5e-4) -> list[dict]:
    """Check the paper's three claims about Fig. 5 against tracking metrics.

    Parameters
    ----------
    metrics : mapping
        ``{frequency_hz: {"pid": {...}, "ct": {...}}}`` with at least 0.5, 1 and 2 Hz,
        each holding the metrics of :func:`pmabayes.control.loop_metrics`.
    settle_tolerance_m : float
        A run whose last two periods differ by more (its ``period_difference_m``, when
        given) has not settled: the claim's verdict still uses its metrics, but names
        it in ``unsettled`` and in the evidence.

    Returns
    -------
    list of dict
        One ``{"claim", "reproduced", "evidence", "unsettled"}`` per claim: computed
        torque better (lower RMS error) than PID at all three frequencies; at 2 Hz PID
        close to 180 degrees out of phase (150-210 taken as close) while computed
        torque stays under 180; about 10% overshoot of computed torque at 1 Hz (5-15%
        taken as about). ``unsettled`` lists the ``"<controller> at <f> Hz"`` runs
        behind the claim that have not settled.

    Examples
    --------
    The claims checked on the metrics of :func:`figure5`'s runs:

    >>> from pmabayes.control.reproduction import figure5, paper_claims
    >>> claims = paper_claims(figure5()["metrics"])
    >>> print(claims[0]["evidence"])
    0.5 Hz: PID 3.37 mm, CT 1.82 mm; 1 Hz: PID 9.41 mm, CT 5.18 mm; 2 Hz: PID 19.78 mm, CT 8.89 mm
    """
    rms = {f: (metrics[f]["pid"]["rms_error_m"], metrics[f]["ct"]["rms_error_m"])
           for f in PAPER_FREQUENCIES_HZ}
    lag_pid = metrics[2.0]["pid"]["phase_lag_deg"]
    lag_ct = metrics[2.0]["ct"]["phase_lag_deg"]
    over = metrics[1.0]["ct"]["overshoot_pct"]

    def unsettled(runs):
        return [f"{c} at {f:g} Hz" for f, c in runs
                if metrics[f][c].get("period_difference_m", 0.0) > settle_tolerance_m]

    claims = [
        {"claim": "computed torque tracks better (lower RMS error) than PID at 0.5, 1 and "
                  "2 Hz",
         "reproduced": bool(all(ct < pid for pid, ct in rms.values())),
         "evidence": "; ".join(f"{f:g} Hz: PID {1e3 * p:.2f} mm, CT {1e3 * c:.2f} mm"
                               for f, (p, c) in rms.items()),
         "unsettled": unsettled([(f, c) for f in PAPER_FREQUENCIES_HZ for c in CONTROLLERS])},
        {"claim": "at 2 Hz PID is close to 180 degrees out of phase (150-210 taken as "
                  "close) while computed torque stays under 180",
         "reproduced": bool(150.0 <= lag_pid <= 210.0 and lag_ct < 180.0),
         "evidence": f"phase lag at 2 Hz: PID {lag_pid:.0f} deg, CT {lag_ct:.0f} deg",
         "unsettled": unsettled([(2.0, "pid"), (2.0, "ct")])},
        {"claim": "computed torque overshoots by about 10% at 1 Hz (5-15% taken as about)",
         "reproduced": bool(5.0 <= over <= 15.0),
         "evidence": f"CT overshoot at 1 Hz: {over:.1f}% of the amplitude",
         "unsettled": unsettled([(1.0, "ct")])},
    ]
    for c in claims:
        if c["unsettled"]:
            c["evidence"] += f" (not settled: {', '.join(c['unsettled'])})"
    return claims


def figure5(*, model: Model | None = None, params=None, plant_model: Model | None = None,
            plant_params: Mapping[str, float] | None = None,
            frequencies_hz: Sequence[float] = PAPER_FREQUENCIES_HZ,
            duration_s: float = 10.0, reference_mean_m: float | None = None,
            gains: Mapping[str, Mapping[str, float]] | None = None) -> dict:
    """Run the paper's Fig. 5 experiment and check its claims.

    Both controllers use the gains of the rule on the controller's model
    (:func:`pmabayes.control.nominal_gains`) unless ``gains`` are given, and the
    reference mean of the operating-point rule on it
    (:func:`pmabayes.control.operating_mean_m`) unless ``reference_mean_m`` is.

    Parameters
    ----------
    model : Model, optional
        The controller's model (and the plant's unless ``plant_model`` is given); the
        base model on :meth:`Rig.control` by default.
    params : mapping or numpy.ndarray, optional
        Its parameters; the paper's values by default.
    plant_model : Model, optional
        A plant that differs from the controller's model, e.g. with a regulator lag
        the model lacks.
    plant_params : mapping, optional
        The plant's parameters (the model's defaults for those not given).
    frequencies_hz : sequence of float
        The panels' frequencies (the paper's 0.5, 1 and 2 Hz).
    duration_s : float
        Length of each run.
    reference_mean_m : float, optional
        Mean of the reference; by default the operating-point rule on the controller's
        model (0.100 m for the paper's values).
    gains : mapping, optional
        Gains per controller, in full or in part (the rest by the rule,
        :func:`pmabayes.control.resolve_gains`).

    Returns
    -------
    dict
        ``run`` (the :class:`pmabayes.control.ClosedLoop`, one run per frequency and
        controller, for :func:`pmabayes.report.figures.plot_figure5`), ``metrics`` (per
        frequency and controller, those of :func:`pmabayes.control.loop_metrics`),
        ``gains`` (those used), ``reference_mean_m`` and ``claims``
        (:func:`paper_claims`; empty unless the frequencies include 0.5, 1 and 2 Hz).

    Examples
    --------
    The paper's Fig. 5 on its own model and gains (about a second):

    >>> from pmabayes.control.reproduction import figure5
    >>> result = figure5()
    >>> sorted(result)
    ['claims', 'gains', 'metrics', 'reference_mean_m', 'run']
    >>> for claim in result["claims"]:
    ...     print(claim["reproduced"], "|", claim["claim"])
    True | computed torque tracks better (lower RMS error) than PID at 0.5, 1 and 2 Hz
    False | at 2 Hz PID is close to 180 degrees out of phase (150-210 taken as close) while ...
    True | computed torque overshoots by about 10% at 1 Hz (5-15% taken as about)
    """
    model = Model(rig=Rig.control()) if model is None else model
    theta = model.theta(params)
    if plant_model is None:
        plant_model, theta_p = model, theta
    else:
        theta_p = plant_model.theta(plant_params)
    if reference_mean_m is None:
        reference_mean_m = operating_mean_m(model, theta)
    gains = resolve_gains(CONTROLLERS, gains, model=model, params=theta,
                          reference_mean_m=reference_mean_m)
    freqs = [float(f) for f in frequencies_hz]
    names = [c for _ in freqs for c in CONTROLLERS]
    fr = np.repeat(freqs, len(CONTROLLERS))
    batch = len(names)
    run = closed_loop_batch(plant_model, np.repeat(theta_p, batch, axis=0), model,
                            np.repeat(theta, batch, axis=0), fr, names, duration_s=duration_s,
                            gains=gain_array(names, gains), reference_mean_m=reference_mean_m)
    per_run = loop_metrics(run)
    metrics: dict[float, dict[str, dict[str, float]]] = {}
    for j, (f, c) in enumerate(zip(fr, names, strict=True)):
        metrics.setdefault(float(f), {})[c] = {k: float(v[j]) for k, v in per_run.items()}
    claims = paper_claims(metrics) if all(f in metrics for f in PAPER_FREQUENCIES_HZ) else []
    return {"run": run, "metrics": metrics, "gains": gains,
            "reference_mean_m": float(reference_mean_m), "claims": claims}
