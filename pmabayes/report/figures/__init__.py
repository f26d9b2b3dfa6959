"""Figures: the model beside the measurements, and the figures of every report.

Every figure of pmabayes is drawn here, from results that are passed in: data sets,
simulations, band errors, correlation curves, rankings, predictive bands, posterior
draws. Nothing here simulates, fits or computes a statistic (those come from
:mod:`pmabayes.criticism`, :mod:`pmabayes.report.fit_data` and
:mod:`pmabayes.control.robustness`). The figures of criticism are in
:mod:`~pmabayes.report.figures.criticism`, those of a fit's report in
:mod:`~pmabayes.report.figures.fit`, those of control in
:mod:`~pmabayes.report.figures.control`.

The library never picks a matplotlib backend: figures are
:class:`matplotlib.figure.Figure` objects, saved with ``fig.savefig`` (which needs
no display and no pyplot), so inline figures in notebooks keep working. Only the
ArviZ trace and rank plots go through pyplot, inside their functions, and close
what they open.
"""

from __future__ import annotations

from pmabayes.report.figures.common import REPORT_DPI
from pmabayes.report.figures.control import plot_figure5, plot_robustness
from pmabayes.report.figures.criticism import (
    plot_band_errors,
    plot_comparison,
    plot_discrepancy,
    plot_ranking,
    plot_residual_signature,
    plot_validation,
    plot_whiteness,
)
from pmabayes.report.figures.fit import (
    plot_pair,
    plot_predictive,
    plot_rank,
    plot_residual,
    plot_trace,
)

__all__ = [
    "REPORT_DPI",
    "plot_comparison",
    "plot_band_errors",
    "plot_residual_signature",
    "plot_whiteness",
    "plot_ranking",
    "plot_discrepancy",
    "plot_figure5",
    "plot_robustness",
    "plot_trace",
    "plot_rank",
    "plot_pair",
    "plot_predictive",
    "plot_residual",
    "plot_validation",
]


def __getattr__(name: str):
    # ``from pmabayes.report.figures import plt`` worked while this module imported pyplot; it is
    # kept for old scripts, loaded only when asked for. Import matplotlib.pyplot instead.
    if name == "plt":
        import matplotlib.pyplot as plt

        return plt
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
