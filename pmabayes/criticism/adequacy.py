"""The one adequacy rule: the whitened residual's energy within a tolerance of pure
noise, and white (:func:`is_adequate`), and a verdict with the numbers and the next
command for reports and the command line (:func:`check_adequacy`, :class:`Adequacy`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from pmabayes.criticism.bands import band_errors, floor_ratio
from pmabayes.criticism.observed import model_mean, residual
from pmabayes.criticism.whiteness import judged_whiteness, p_text
from pmabayes.inference.likelihood import (
    LEVEL_ADEQUATE,
    Likelihood,
    slow_disturbance_note,
)
from pmabayes.util import finite_or_none

__all__ = ["ENERGY_TOLERANCE", "is_adequate", "Adequacy", "check_adequacy"]


#: Largest excess of the whitened residual's mean square over pure noise (1) for an
#: adequate model. A tolerance, not a chi-squared test: with the noise parameters
#: estimated from a few trials the energy of pure noise scatters by about 0.03
#: around 1 (measured), twice the chi-squared spread. 0.1 means a model error below
#: about a third of the noise level.
ENERGY_TOLERANCE = 0.1


def is_adequate(energy: float, ljung_box_p: float, *,
                energy_tolerance: float = ENERGY_TOLERANCE,
                level_adequate: float = LEVEL_ADEQUATE) -> bool:
    """The adequacy rule: the whitened residual is consistent with the noise.

    Its mean square is within ``1 + energy_tolerance`` of pure noise and its
    autocorrelation is not significant (Ljung-Box p at least ``level_adequate``).

    Parameters
    ----------
    energy : float
        Mean square of the whitened residual.
    ljung_box_p : float
        Its Ljung-Box p-value.
    energy_tolerance : float
        See :data:`ENERGY_TOLERANCE`.
    level_adequate : float
        See :data:`~pmabayes.inference.likelihood.LEVEL_ADEQUATE`.

    Returns
    -------
    bool
    """
    return bool(energy <= 1.0 + energy_tolerance and ljung_box_p >= level_adequate)


@dataclass(frozen=True)
class Adequacy:
    """Whether a fitted model describes the data, in numbers and words.

    Convergence of a sampler says that the posterior of the model is well
    sampled; this says whether the model itself fits. A report or a command prints
    :meth:`lines` beside the convergence check.

    Parameters
    ----------
    adequate : bool or None
        The rule of :func:`is_adequate`; None when the whitened residual could not
        be computed (no noise estimate).
    rms_m : float
        RMS of the trial mean minus the model.
    floor_m : float
        Noise floor: the RMS a perfect model would have.
    energy : float or None
        Mean square of the whitened residual (1 for pure noise).
    ljung_box_p : float or None
        Ljung-Box p-value of the whitened residual.
    coverage : float or None
        Fraction of the measured samples inside the central posterior predictive
        band of probability ``ci_prob``, when known.
    ci_prob : float
        Probability of that band.
    next_command : str
        The command that diagnoses what is missing (``pmabayes diagnose DATA``).
    energy_tolerance : float
        Tolerance used for ``adequate``.
    level_adequate : float
        Ljung-Box level used for ``adequate``.
    noise_model : str
        The noise model the residual was whitened with
        (:func:`~pmabayes.criticism.whiteness.judged_whiteness`).
    noise_note : str
        What the data cannot tell about the noise, when a record without repeats has a
        slow disturbance (:func:`~pmabayes.inference.likelihood.slow_disturbance_note`);
        empty otherwise.
    """

    adequate: bool | None
    rms_m: float
    floor_m: float
    energy: float | None
    ljung_box_p: float | None
    coverage: float | None = None
    ci_prob: float = 0.9
    next_command: str = ""
    energy_tolerance: float = ENERGY_TOLERANCE
    level_adequate: float = LEVEL_ADEQUATE
    noise_model: str = "AR(1) + white"
    noise_note: str = ""

    @property
    def ratio(self) -> float:
        """``rms_m / floor_m``: about 1 for a model that describes the data (NaN, no floor)."""
        return floor_ratio(self.rms_m, self.floor_m)

    @property
    def headline(self) -> str:
        """``MODEL INADEQUATE``, ``Model adequate`` or ``Model adequacy unknown``."""
        if self.adequate is None:
            return "Model adequacy unknown"
        return "Model adequate" if self.adequate else "MODEL INADEQUATE"

    def evidence(self) -> str:
        """The numbers behind the verdict in one sentence."""
        text = (f"the error of the trial mean is {self.ratio:.3g}x the noise floor (RMS "
                f"{self.rms_m * 1e6:.4g} µm against {self.floor_m * 1e6:.4g} µm)"
                if math.isfinite(self.floor_m) else
                f"the RMS error is {self.rms_m * 1e6:.4g} µm (no repeats: no noise floor)")
        if self.energy is not None:
            text += (f"; the whitened residual's energy is {self.energy:.3g} (1 for pure "
                     f"noise, at most {1 + self.energy_tolerance:g} allowed) and its "
                     f"Ljung-Box {p_text(self.ljung_box_p)} (at least "
                     f"{self.level_adequate:g} needed)")
            if self.noise_model != "AR(1) + white":
                text += (f", whitened with an {self.noise_model} since the deviations between "
                         "trials reject AR(1) + white")
        if self.coverage is not None:
            text += (f"; {self.coverage:.1%} of the data lie inside the {self.ci_prob:.0%} "
                     "posterior predictive band")
        return text

    def advice(self) -> list[str]:
        """What the verdict means, in sentences (for an adequate model, only what the
        data cannot tell about the noise, if anything).

        Returns
        -------
        list of str
        """
        note = [f"But {self.noise_note}."] if self.noise_note else []
        if self.adequate is None:
            return ["The fit holds no noise estimate, so the whitened residual cannot be "
                    "judged."]
        if self.adequate is False:
            return ["The sampler's convergence is not the model's fit: the intervals are "
                    "those of a model that the data reject.", *note]
        return note

    @property
    def next_step(self) -> str | None:
        """The command to run next: ``next_command`` unless the model is adequate."""
        return self.next_command if self.adequate is not True and self.next_command else None

    def lines(self) -> list[str]:
        """The verdict as lines of text, for a terminal.

        Returns
        -------
        list of str
            The headline with the evidence; for an inadequate model, what it
            means and the next command (``Next: pmabayes diagnose DATA``).
        """
        out = [f"{self.headline}: {self.evidence()}.", *self.advice()]
        return out + ([f"Next: {self.next_step}"] if self.next_step else [])

    def to_dict(self) -> dict:
        """JSON-ready values.

        Returns
        -------
        dict
        """
        return {"adequate": self.adequate, "rms_m": self.rms_m,
                "floor_m": finite_or_none(self.floor_m), "ratio": finite_or_none(self.ratio),
                "energy": self.energy, "ljung_box_p": self.ljung_box_p,
                "coverage": self.coverage, "ci_prob": self.ci_prob,
                "next_command": self.next_command, "energy_tolerance": self.energy_tolerance,
                "level_adequate": self.level_adequate, "noise_model": self.noise_model,
                "noise_note": self.noise_note}


def check_adequacy(
    likelihood: Likelihood,
    model_position_m: np.ndarray,
    noise=None,
    *,
    coverage: float | None = None,
    ci_prob: float = 0.9,
    next_command: str = "",
) -> Adequacy:
    """Judge whether a model output describes the data (the rule of :func:`is_adequate`).

    Parameters
    ----------
    likelihood : Likelihood
        The data and its noise model.
    model_position_m : numpy.ndarray
        Model output on the data's time grid, ``(n_samples,)``; each trial's
        ``(n_trials, n_samples)`` where the trials have their own inputs.
    noise : object, optional
        Identified noise (``sigma``, ``rho``, ``white``); without it the whitened
        residual is not computed and the verdict is unknown.
    coverage : float, optional
        Fraction of the data inside the posterior predictive band, to quote.
    ci_prob : float
        Probability of that band.
    next_command : str
        The command that diagnoses the model, to quote when it is not adequate.

    Returns
    -------
    Adequacy
        With the default tolerance and level (:data:`ENERGY_TOLERANCE`,
        :data:`~pmabayes.inference.likelihood.LEVEL_ADEQUATE`), as
        :func:`pmabayes.criticism.diagnosis.diagnose` uses by default.
    """
    x = np.asarray(model_position_m, dtype=float)
    trials = None
    if likelihood.own_inputs and x.ndim == 2 and x.shape[0] == likelihood.n_trials:
        trials, x = x, model_mean(likelihood, x.reshape(1, -1))[0]
    x = x.reshape(-1)
    if likelihood.dataset.n_trials >= 2 or likelihood.noise_source == "periods":
        # the floor as diagnose takes it: of the trials, or of a periodic record's periods
        overall = band_errors(likelihood.dataset, x, bands_hz=(), model_trials_m=trials)[-1]
    else:  # a single record: its error, and no floor without repeats
        r = residual(likelihood, x)
        r = r if likelihood.observed is None else r[np.isfinite(r)]
        overall = SimpleNamespace(rms_m=float(np.sqrt(np.mean(r * r))), floor_m=math.nan)
    energy = lb_p = adequate = None
    noise_model, note = "AR(1) + white", ""
    if noise is not None:
        _, white, noise_check = judged_whiteness(likelihood, x, noise)
        energy, lb_p = white["energy"], white["ljung_box_p"]
        adequate = is_adequate(energy, lb_p)
        noise_model = noise_check.noise_model
        note = slow_disturbance_note(likelihood, noise.rho)
    return Adequacy(adequate=adequate, rms_m=overall.rms_m, floor_m=overall.floor_m,
                    energy=energy, ljung_box_p=lb_p, coverage=coverage, ci_prob=ci_prob,
                    next_command=next_command, noise_model=noise_model, noise_note=note)
