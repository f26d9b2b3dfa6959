"""The residual's signature: where and how a model's trial-mean residual departs from
the noise (errors per band, whiteness, and the correlations that say where it fails).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmabayes.criticism.adequacy import ENERGY_TOLERANCE, is_adequate
from pmabayes.criticism.bands import band_errors, band_label
from pmabayes.criticism.observed import residual, shared_input
from pmabayes.criticism.whiteness import cross_correlation, judged_whiteness
from pmabayes.inference.likelihood import (
    LEVEL_ADEQUATE,
    Likelihood,
)

__all__ = ["Signature", "residual_signature"]


@dataclass(frozen=True)
class Signature:
    """Where and how a model's trial-mean residual departs from the noise.

    Parameters
    ----------
    bands : list of BandErrors
        Errors per frequency band, the last one overall.
    ljung_box_p : float
        Ljung-Box p-value (25 lags) of the whitened residual.
    energy : float
        Mean square of the whitened residual: 1 for pure noise.
    energy_p : float
        p-value of ``energy`` against pure noise (chi-squared, one-sided).
    correlations : dict
        Correlation of the residual with the model's position, velocity and
        pressure and with the rate of change of the command.
    ccf_lag_s : float
        Lag at which the whitened residual correlates most with the earlier rate
        of change of the command (positive: the residual follows the command).
    ccf_peak : float
        That correlation.
    ccf_bound : float
        Its 99% bound for independent series.
    noise_model : str
        The noise model the residual was whitened with: ``"AR(1) + white"``, or an
        AR model of the repeats when those reject AR(1) + white
        (:func:`~pmabayes.criticism.whiteness.judged_whiteness`).
    """

    bands: list
    ljung_box_p: float
    energy: float
    energy_p: float
    correlations: dict
    ccf_lag_s: float
    ccf_peak: float
    ccf_bound: float
    noise_model: str = "AR(1) + white"

    @property
    def ratio(self) -> float:
        """Overall RMS error over the noise floor."""
        return self.bands[-1].ratio

    def is_adequate(self, energy_tolerance: float = ENERGY_TOLERANCE,
                    level_adequate: float = LEVEL_ADEQUATE) -> bool:
        """Whether the residual is consistent with the noise (see :func:`is_adequate`).

        Parameters
        ----------
        energy_tolerance : float
            Largest excess of the whitened residual's mean square over 1.
        level_adequate : float
            Level of the Ljung-Box test.

        Returns
        -------
        bool
        """
        return is_adequate(self.energy, self.ljung_box_p, energy_tolerance=energy_tolerance,
                           level_adequate=level_adequate)

    def describe(self) -> str:
        """The signature in one or two plain sentences, from the numbers."""
        # the band above the command's carries mostly noise, and the lowest one the
        # offset and the leakage of the ends' mismatch: either would hide a trend
        bands = [b for b in self.bands[:-1] if b.n_samples > 0 and math.isfinite(b.band_hz[1])]
        if sum(b.band_hz[0] > 0 for b in bands) >= 2:
            bands = [b for b in bands if b.band_hz[0] > 0]
        overall = self.bands[-1]
        if math.isnan(overall.floor_m):
            text = (f"The error is {overall.rms_m * 1e6:.4g} µm RMS ({overall.nrms:.3g} of the "
                    "motion; a single record without repeats, so no noise floor)")
            return text + "." + self._describe_correlations()
        ratios = [b.ratio for b in bands]
        text = (f"The error is {overall.rms_m * 1e6:.4g} µm RMS against a noise floor of "
                f"{overall.floor_m * 1e6:.4g} µm ({overall.ratio:.3g}x)")
        if len(bands) >= 2:
            lo, hi = bands[0], bands[-1]
            span = (f"from {lo.ratio:.3g}x the floor at {band_label(lo.band_hz)} to "
                    f"{hi.ratio:.3g}x at {band_label(hi.band_hz)}")
            if hi.ratio > 2.0 * lo.ratio:
                text += f"; it grows with frequency, {span}"
            elif lo.ratio > 2.0 * hi.ratio:
                text += f"; it is largest at low frequency, {span}"
            else:
                text += (f"; it is spread over the band the input excites ({min(ratios):.3g}x "
                         f"to {max(ratios):.3g}x the floor per band)")
        return text + "." + self._describe_correlations()

    def _describe_correlations(self) -> str:
        text = ""
        if self.correlations:
            name, value = max(self.correlations.items(), key=lambda kv: abs(kv[1]))
            text += f" The residual correlates most with the {name} (r = {value:+.2f})."
        if abs(self.ccf_peak) > self.ccf_bound and self.ccf_lag_s > 0:
            # residual = data - model; a response that trails the model's is
            # x(t - tau) - x(t) ~ -tau dx/dt: negative against the command's rate
            how = ("the measured response trails the model's, as if the pressure acted later "
                   "than the model assumes" if self.ccf_peak < 0 else
                   "the measured response runs ahead of the model's")
            text += (f" The whitened residual still correlates with the rate of change of the "
                     f"command {self.ccf_lag_s * 1e3:.0f} ms earlier (correlation "
                     f"{self.ccf_peak:+.2f}, {abs(self.ccf_peak) / self.ccf_bound:.0f}x its 99% "
                     f"bound): {how}.")
        if self.ljung_box_p < 0.01:
            text += f" The whitened residual is not white (Ljung-Box p = {self.ljung_box_p:.2g})."
        if self.noise_model != "AR(1) + white":
            text += (f" (Whitened with an {self.noise_model}: the deviations between trials "
                     "reject the AR(1) + white noise model.)")
        return text


def residual_signature(likelihood: Likelihood, noise, sim, *, max_lag_s: float = 0.2,
                       model_trials_m: np.ndarray | None = None) -> Signature:
    """Measure the signature of a model's residual on the data.

    With samples not counted (gaps, a warm-up) every statistic takes the samples
    counted (:mod:`~pmabayes.criticism.observed`): the correlations, the whitened
    residual (NaN there: the filter predicts across), its whiteness over the pairs
    both observed, and the errors per band.

    Parameters
    ----------
    likelihood : Likelihood
        Data and noise model.
    noise : object
        Identified noise (``sigma``, ``rho``, ``white``).
    sim : pmabayes.model.simulator.Simulation
        The model's simulation (batch of one) with its states: its trial mean where the
        trials have their own inputs
        (:func:`~pmabayes.criticism.observed.simulate_states`).
    max_lag_s : float
        Largest lag of the cross-correlation with the command's rate.
    model_trials_m : numpy.ndarray, optional
        Each trial's model position ``(n_trials, n_samples)`` where the trials have
        their own inputs (for the noise floor of their residuals).

    Returns
    -------
    Signature
    """
    ds = likelihood.dataset
    x = sim.position_m[0]
    r = residual(likelihood, x)
    e, white, noise_check = judged_whiteness(likelihood, x, noise)
    rate = np.gradient(shared_input(ds), ds.time_s)
    signals = {"position": x, "velocity": sim.velocity_m_s[0], "pressure": sim.pressure_pa[0],
               "pressure rate": rate}
    seen = np.isfinite(r)
    corr = {}
    for name, s in signals.items():
        if not seen.all():
            s, r_seen = s[seen], r[seen]
            if np.std(s) > 0 and np.std(r_seen) > 0:
                corr[name] = float(np.corrcoef(r_seen, s)[0, 1])
        elif np.std(s) > 0 and np.std(r) > 0:
            corr[name] = float(np.corrcoef(r, s)[0, 1])
    max_lag = max(1, int(round(max_lag_s / ds.dt_s)))
    lags_r, ccf_r, bound = cross_correlation(e, rate, max_lag=max_lag)
    pos = lags_r >= 0
    k = int(np.argmax(np.abs(ccf_r[pos])))
    return Signature(
        bands=band_errors(ds, x, model_trials_m=model_trials_m),
        ljung_box_p=white["ljung_box_p"], energy=white["energy"],
        energy_p=white["energy_p"], correlations=corr,
        ccf_lag_s=float(lags_r[pos][k] * ds.dt_s), ccf_peak=float(ccf_r[pos][k]),
        ccf_bound=bound, noise_model=noise_check.noise_model,
    )
