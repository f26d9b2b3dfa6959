"""Experimental design: the next experiment that tells candidate effects apart, or that
shrinks chosen parameters' intervals.

:func:`~pmabayes.design.api.design` fits each candidate model on the data so far, draws
candidate experiments (:mod:`~pmabayes.design.experiments`: chirps, steps and holds,
band-limited noise, sines, dead loads, within the rig's input range and a duration
budget), simulates every model's posterior draws on each in one batched call, and scores
them (:mod:`~pmabayes.design.score`: the expected log Bayes factor of the true model and
the rate at which it is named, with their Monte Carlo errors; or the expected shrinkage
of intervals). :mod:`~pmabayes.design.files` writes the chosen input as a plan in the
user's units; :func:`pmabayes.report.design_page.write_design` adds the page.
"""

from pmabayes.design.api import GOALS, DesignResult, design
from pmabayes.design.experiments import FAMILIES, DesignError, Experiment
from pmabayes.design.files import write_design_files
from pmabayes.design.fits import CandidateFit, fit_candidate

__all__ = ["design", "DesignResult", "DesignError", "Experiment", "CandidateFit",
           "fit_candidate", "write_design_files", "FAMILIES", "GOALS"]
