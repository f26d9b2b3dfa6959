"""What can stop a fit, and what it warns of."""

from __future__ import annotations

__all__ = ["FitError", "ConvergenceWarning"]


class FitError(RuntimeError):
    """A fit cannot proceed or produced nonsense (the data does not fit the model)."""


class ConvergenceWarning(RuntimeWarning):
    """A fit spent its budget before the sampler converged (its result is still returned)."""
