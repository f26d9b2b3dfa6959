"""Reports: the HTML pages and summary tables of fits, diagnoses, comparisons and
validations (figures in :mod:`pmabayes.report.figures`).
"""

from pmabayes.report.pages import (
    SUMMARY_COLUMNS,
    experiment_adequacy,
    fit_adequacy,
    pair_figure,
    predictive_band,
    summary_table,
    write_comparison,
    write_diagnosis,
    write_report,
    write_summary,
    write_validation,
)

__all__ = [
    "SUMMARY_COLUMNS",
    "summary_table",
    "write_summary",
    "write_report",
    "write_diagnosis",
    "write_comparison",
    "pair_figure",
    "predictive_band",
    "fit_adequacy",
    "experiment_adequacy",
    "write_validation",
]
