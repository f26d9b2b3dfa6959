"""A model refitted with one more effect (:class:`Refit`), and why its ΔELPD may have no
standard error (:func:`se_note`): below the diagnosis' results and its prose, which both
read refits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmabayes.util import finite_or_none

__all__ = ["Refit", "se_note"]


@dataclass(frozen=True)
class Refit:
    """A model refitted with one more effect (MAP with a Laplace posterior).

    Parameters
    ----------
    effect : str
        The added effect.
    values : dict
        MAP of every parameter of the extended model.
    interval : dict
        ``(low, high)`` equal-tailed interval of each of the effect's free
        parameters at the diagnosis' ``ci_prob``, from Laplace draws.
    rms_m : float
        RMS error of the trial mean at the MAP.
    explained : float
        Fraction of the base model's excess whitened residual energy (above pure
        noise) that the refit removes.
    elpd : float
        Leave-one-trial-out ELPD (PSIS-LOO over Laplace draws).
    elpd_diff : float
        ``elpd`` minus the base model's: positive when the effect predicts left-out
        trials better.
    elpd_diff_se : float
        Standard error of ``elpd_diff`` from the per-trial differences.
    contribution_m : numpy.ndarray
        The effect's contribution to the model output at the MAP: the output minus
        the output with the effect switched off (its null values).
    next_effect : str or None
        The significant candidate that best explains what the refit leaves (score
        test on the refit), if any; looked for only when the refit alone does not
        account for the misfit.
    explained_with_next : float
        Fraction of the base model's excess removed by the refit and, to first
        order, by ``next_effect`` after it: near 1 when the two together account
        for the misfit.
    signatures : tuple of Signature
        The refitted model's residual signature in each experiment, in the
        diagnosis' order.
    elpd_i : numpy.ndarray or None
        Per-trial leave-one-out ELPD, for paired comparisons of refits.
    explained_rms : float or None
        Fraction of the base model's mean-square error above the noise floor that
        the refit removes (:func:`pmabayes.criticism.bands.excess_removed`), the
        share the words report beside the RMS errors; None without a floor.
    adequate : bool
        Whether the refitted model is adequate in every experiment.
    implausible : str or None
        Why the refit's estimates are not physics (outside their plausible range, or
        run to a bound: :func:`pmabayes.criticism.plausibility.implausible`); such a
        refit is never named missing. None when they are plausible.
    failed : str or None
        Why the refit's search failed (its MAP fits worse than the model without the
        effect, which it holds: :func:`pmabayes.criticism.refits.refit_failure`); its
        ELPD and errors are then not the effect's, and it is never named. None when it
        succeeded.
    agreement : dict or None
        With several experiments, whether they agree on one parameter set once the
        effect is added (:func:`pmabayes.inference.search.experiments_agreement`).

    Notes
    -----
    ``rms_m`` is pooled over every sample of every experiment, and
    ``contribution_m`` is the experiments' contributions concatenated along time,
    in order.
    """

    effect: str
    values: dict
    interval: dict
    rms_m: float
    explained: float
    elpd: float
    elpd_diff: float
    elpd_diff_se: float
    contribution_m: np.ndarray
    next_effect: str | None = None
    explained_with_next: float = 0.0
    signatures: tuple = ()
    elpd_i: np.ndarray | None = None
    explained_rms: float | None = None
    adequate: bool = False
    implausible: str | None = None
    failed: str | None = None
    agreement: dict | None = None

    def to_dict(self) -> dict:
        """JSON-ready summary: ``rms_m`` (pooled), ``explained`` (whitened energy),
        ``explained_rms`` (mean square above the floor), ``adequate``, ``elpd_diff``
        and ``elpd_diff_se`` (None where not estimable: the standard error of one
        left-out unit), ``elpd_diff_se_note`` (why it is None, else None), ``implausible``,
        ``failed`` and ``experiments``, one ``{"rms_m", "noise_ratio", "ljung_box_p",
        "energy"}`` each.

        Returns
        -------
        dict
        """
        return {"rms_m": self.rms_m, "explained": self.explained,
                "explained_rms": self.explained_rms, "adequate": self.adequate,
                "elpd_diff": finite_or_none(self.elpd_diff),
                "elpd_diff_se": finite_or_none(self.elpd_diff_se),
                "elpd_diff_se_note": se_note(self),
                "implausible": self.implausible, "failed": self.failed,
                "experiments": [{"rms_m": sig.bands[-1].rms_m,
                                 "noise_ratio": finite_or_none(sig.ratio),
                                 "ljung_box_p": sig.ljung_box_p, "energy": sig.energy}
                                for sig in self.signatures]}


def se_note(refit: Refit) -> str | None:
    """Why a refit's ΔELPD has no standard error, or None when it has one.

    Parameters
    ----------
    refit : Refit
        The refit.

    Returns
    -------
    str or None
    """
    if math.isfinite(refit.elpd_diff_se) or not math.isfinite(refit.elpd_diff):
        return None
    return ("one left-out unit (a single record whose noise model cannot leave out "
            "stretches of it): no spread to estimate a standard error from")
