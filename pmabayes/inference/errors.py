"""What can stop a fit, and what it warns of."""

from __future__ import annotations

__all__ = ["FitError", "ConvergenceWarning", "DisagreementWarning", "PoorFitWarning"]


class FitError(RuntimeError):
    """A fit cannot proceed: no finite simulation, or data that no model of this kind
    explains (a wrong sign or scale). A merely poor fit is not an error
    (:class:`PoorFitWarning`)."""


class ConvergenceWarning(RuntimeWarning):
    """A fit spent its budget before the sampler converged (its result is still returned)."""


class DisagreementWarning(UserWarning):
    """A joint fit's experiments disagree: their own optima are not compatible with one
    shared parameter set (:func:`pmabayes.inference.search.experiments_agreement`)."""


class PoorFitWarning(UserWarning):
    """The best fit misses much of the motion, or ends worse than the static line the
    model contains (:func:`pmabayes.inference.search.fit_quality`); the fit is still
    returned, and :func:`pmabayes.diagnose` says where it fails."""
