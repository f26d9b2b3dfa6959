"""What can stop a fit, and what it warns of."""

from __future__ import annotations

__all__ = ["FitError", "ConvergenceWarning", "DisagreementWarning"]


class FitError(RuntimeError):
    """A fit cannot proceed or produced nonsense (the data does not fit the model)."""


class ConvergenceWarning(RuntimeWarning):
    """A fit spent its budget before the sampler converged (its result is still returned)."""


class DisagreementWarning(UserWarning):
    """A joint fit's experiments disagree: their own optima are not compatible with one
    shared parameter set (:func:`pmabayes.inference.search.experiments_agreement`)."""
