"""Reports: the HTML pages and summary tables of fits, diagnoses, comparisons and
validations, and every figure of pmabayes (:mod:`pmabayes.report.figures`).

==================== ===============================================================
``markup``           the pieces every page is built of (CSS, tables, embedded figures)
``fit_data``         what the reports read from a fit; its posterior predictive band
``summary``          the summary table of a fit (CSV, Markdown) and its corner plot
``verdicts``         whether a fitted model describes its data, per experiment
``fit_page``         the report of a fit
``diagnosis_page``   the page of a diagnosis
``comparison_page``  the page of a comparison of fits
``validation_page``  the page of a validation on held-out experiments
``figures``          the figures, drawn from results passed in (a package)
==================== ===============================================================
"""

from pmabayes.report.comparison_page import write_comparison
from pmabayes.report.diagnosis_page import write_diagnosis
from pmabayes.report.fit_data import predictive_band
from pmabayes.report.fit_page import write_report
from pmabayes.report.summary import SUMMARY_COLUMNS, pair_figure, summary_table, write_summary
from pmabayes.report.validation_page import write_validation
from pmabayes.report.verdicts import experiment_adequacy, fit_adequacy

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
