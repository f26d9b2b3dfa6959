"""Student-t white noise: independent samples with heavy tails, for records with outliers.

Each sample's residual is ``sigma_t_m`` times a Student-t variable of ``nu_t`` degrees
of freedom, independent of every other sample. A Gaussian noise model lets a few gross
outliers (a sensor's spikes, a dropped sample) pull the fit towards them; a Student-t
one weighs a residual ``r`` by ``(nu + 1) / (nu + (r / sigma)^2)``, so that an outlier
counts little. Its parameters are sampled with the model's (no repeats are needed), and
the likelihood of repeated trials is each trial's, summed (the trial mean of Student-t
noise is not Student-t). Selected by ``noise_model="student_t"``
(:class:`pmabayes.inference.FitSettings`, ``--noise-model student_t``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from scipy import special, stats

from pmabayes.inference.noise.ar1 import NOISE_PER_AMPLITUDE, scaled_to_motion
from pmabayes.inference.noise.base import NoiseModel, register_noise_model
from pmabayes.model.parameters import LogNormal, Parameter

if TYPE_CHECKING:
    from pmabayes.inference.likelihood import Likelihood

__all__ = ["STUDENT_T_PARAMETERS", "StudentT"]

#: The Student-t noise's parameters: its scale (the muscle's disturbance's prior) and
#: its degrees of freedom (median 5: heavy tails; from about 30 on it is Gaussian).
#:
#: :meta hide-value:
STUDENT_T_PARAMETERS: tuple[Parameter, ...] = (
    Parameter(
        "sigma_t_m", "m", 5e-5, LogNormal(5e-5, 2.0), bounds=(0.0, math.inf),
        description="scale of each sample's Student-t noise (independent samples)",
        latex=r"\sigma_t",
    ),
    Parameter(
        "nu_t", "1", 5.0, LogNormal(5.0, 1.0), bounds=(1.0, 1000.0),
        description="degrees of freedom of the Student-t noise (small: heavy tails, "
                    "outliers; large: Gaussian)",
        latex=r"\nu",
    ),
)


@register_noise_model
class StudentT(NoiseModel):
    """Independent Student-t noise per sample (see the module's docstring)."""

    name = "student_t"
    splits_mean = False
    description = ("Student-t white noise per sample (heavy tails for outliers), "
                   "independent between samples and trials")
    label = "Student-t white"

    def parameters(self, likelihood: Likelihood) -> tuple[Parameter, ...]:
        """:data:`STUDENT_T_PARAMETERS`, the scale on the data's for a force-input rig
        (:data:`~pmabayes.inference.noise.ar1.NOISE_PER_AMPLITUDE`).

        Parameters
        ----------
        likelihood : Likelihood

        Returns
        -------
        tuple of Parameter
        """
        sig, nu = STUDENT_T_PARAMETERS
        if likelihood.model.rig.input_kind == "force":  # an oscillator's scale is the data's
            sig = scaled_to_motion(sig, likelihood, NOISE_PER_AMPLITUDE)
        return (sig, nu)

    def log_likelihood(self, y: np.ndarray, x: np.ndarray, scale: float, noise: tuple,
                       observed: np.ndarray | None = None) -> np.ndarray:
        """The sum over the samples observed of the Student-t log density of
        ``scale * (y[m] - x[b, m or 0])``, ``(batch, series)``."""
        sigma, nu = (np.asarray(v, dtype=float)[:, None] for v in noise)
        const = (special.gammaln(0.5 * (nu + 1.0)) - special.gammaln(0.5 * nu)
                 - 0.5 * np.log(nu * math.pi) - np.log(sigma))
        out = np.empty((sigma.shape[0], y.shape[0]))
        for m in range(y.shape[0]):  # one series at a time: a batch of long records is large
            u = scale * (y[m] - x[:, m if x.shape[1] > 1 else 0]) / sigma
            terms = const - 0.5 * (nu + 1.0) * np.log1p(u * u / nu)
            if observed is not None:
                terms = np.where(observed[m if observed.shape[0] > 1 else 0], terms, 0.0)
            out[:, m] = terms.sum(axis=1)
        return out

    def whiten(self, v: np.ndarray, scale: float, noise: tuple,
               seen: np.ndarray | None = None) -> np.ndarray:
        """``Phi^-1(F_t(scale v / sigma))``: independent N(0, 1) when the noise model
        holds (the samples are independent already); NaN where not ``seen``."""
        sigma, nu = (float(np.asarray(p).reshape(-1)[0]) for p in noise)
        out = stats.norm.ppf(stats.t.cdf(scale * np.asarray(v, dtype=float) / sigma, nu))
        return out if seen is None else np.where(seen, out, np.nan)

    def draw(self, n_series: int, n_samples: int, noise: tuple,
             rng: np.random.Generator) -> np.ndarray:
        """``sigma`` times standard Student-t draws (``noise``: scalars or one per series)."""
        sigma, nu = (np.broadcast_to(np.asarray(v, dtype=float), (n_series,))[:, None]
                     for v in noise)
        return sigma * rng.standard_t(nu, size=(n_series, n_samples))

    def start(self, residual: np.ndarray, observed: np.ndarray | None,
              likelihood: Likelihood) -> tuple[np.ndarray, np.ndarray]:
        """The scale from the residual's median absolute deviation (robust to the
        outliers), 5 degrees of freedom; the second start nearly Gaussian (30)."""
        r = residual if observed is None else residual[observed[0]]
        mad = float(np.median(np.abs(r - np.median(r))))
        s0 = 1.4826 * mad if mad > 0 else max(float(np.std(r)), 1e-12)
        return np.array([math.log(s0), math.log(5.0)]), np.array([0.0, math.log(6.0)])

    def to_dict(self) -> dict:
        """``{"noise_model": "student_t"}``: its parameters are the fit's draws."""
        return {"noise_model": self.name}
