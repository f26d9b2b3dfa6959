"""A model refitted with one more effect (:class:`Refit`), with why its ΔELPD may have no
standard error, whether an unreliable one is confirmed and whether it carries to
experiments left out: below the diagnosis' results and its prose, which both read refits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmabayes.criticism.elpd import LaplaceLoo
from pmabayes.criticism.transfer import Transfer
from pmabayes.util import finite_or_none

__all__ = ["Refit"]


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
    elpd_note : str or None
        Why ``elpd_diff`` is not a reliable estimate (the refit's or the base model's
        PSIS-LOO: a Pareto k-hat of its importance weights above the threshold, a Laplace
        covariance that is a stand-in; :class:`pmabayes.criticism.elpd.LaplaceLoo`);
        such a ΔELPD names nothing unless ``plugin_diff`` agrees. None when reliable.
    plugin_diff : float
        The witness that needs no draws: the in-sample log likelihoods at the two MAPs,
        paired over the units, less the parameters the effect adds
        (:func:`pmabayes.criticism.elpd.plugin_difference`); NaN where not computed.
    plugin_diff_se : float
        Its standard error from the per-unit differences.
    loo : LaplaceLoo or None
        The refit's own ELPD estimate (its reliability, its units' log likelihoods at
        the MAP), to compare refits with each other; not in :meth:`to_dict`.
    transfer : Transfer or None
        With several experiments, the refit and the model each fitted to all but one
        and predicting the one left out, in turn
        (:func:`pmabayes.criticism.transfer.leave_experiments_out`); a refit that
        predicts them worse is never named (:attr:`carries`). None where not checked.

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
    elpd_note: str | None = None
    plugin_diff: float = math.nan
    plugin_diff_se: float = math.nan
    loo: LaplaceLoo | None = None
    transfer: Transfer | None = None

    @property
    def se_note(self) -> str | None:
        """Why the ΔELPD has no standard error, or None when it has one (or no ΔELPD)."""
        if math.isfinite(self.elpd_diff_se) or not math.isfinite(self.elpd_diff):
            return None
        return ("one left-out unit (a single record whose noise model cannot leave out "
                "stretches of it): no spread to estimate a standard error from")

    @property
    def witnessed(self) -> bool:
        """Whether the ΔELPD may be read as it stands: its estimate is reliable, or the
        in-sample witness (:attr:`plugin_diff`) agrees that it rises (by more than two
        standard errors; where there is no standard error, one left-out unit, above
        zero)."""
        if self.elpd_note is None:
            return True
        d, se = self.plugin_diff, self.plugin_diff_se
        if not math.isfinite(d):
            return False
        return bool(d > 2.0 * se if math.isfinite(se) else d > 0.0)

    @property
    def carries(self) -> bool:
        """Whether nothing says the refit predicts experiments it was not fitted to
        worse: not checked, not decidable, or a lower mean NRMSE on the experiments
        left out (:attr:`transfer`)."""
        return self.transfer is None or self.transfer.carries is not False

    def to_dict(self) -> dict:
        """JSON-ready summary: ``rms_m`` (pooled), ``explained`` (whitened energy),
        ``explained_rms`` (mean square above the floor), ``adequate``, ``elpd_diff``
        and ``elpd_diff_se`` (None where not estimable: the standard error of one
        left-out unit), ``elpd_diff_se_note`` (why it is None, else None),
        ``elpd_note`` (why the ΔELPD is not reliable, else None), ``plugin_diff`` and
        ``plugin_diff_se`` (its in-sample witness, None where not computed),
        ``implausible``, ``failed``, ``experiments``, one ``{"rms_m", "noise_ratio",
        "ljung_box_p", "energy"}`` each, and ``left_out_experiments``
        (:meth:`~pmabayes.criticism.transfer.Transfer.to_dict`, None where not checked).

        Returns
        -------
        dict
        """
        return {"rms_m": self.rms_m, "explained": self.explained,
                "explained_rms": self.explained_rms, "adequate": self.adequate,
                "elpd_diff": finite_or_none(self.elpd_diff),
                "elpd_diff_se": finite_or_none(self.elpd_diff_se),
                "elpd_diff_se_note": self.se_note,
                "elpd_note": self.elpd_note,
                "plugin_diff": finite_or_none(self.plugin_diff),
                "plugin_diff_se": finite_or_none(self.plugin_diff_se),
                "implausible": self.implausible, "failed": self.failed,
                "experiments": [{"rms_m": sig.bands[-1].rms_m,
                                 "noise_ratio": finite_or_none(sig.ratio),
                                 "ljung_box_p": sig.ljung_box_p, "energy": sig.energy}
                                for sig in self.signatures],
                "left_out_experiments": (None if self.transfer is None
                                         else self.transfer.to_dict())}

