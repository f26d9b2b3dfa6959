"""Criticism and validation: residual statistics and the adequacy rule, the score tests
and refits of candidate effects, the data-driven discrepancy, comparisons of fits, and
predictions of held-out experiments.

Each file owns one idea:

=================  ==================================================================
``bands``          errors of the trial mean per frequency band, against the noise floor
``whiteness``      whiteness and independence of the whitened residual; the noise check
``signature``      the residual's signature: where and how a model fails
``adequacy``       the one adequacy rule and its verdict in words
``scores``         score tests of candidate effects, with no refit
``plausibility``   whether an estimate is physics: each parameter's plausible range
``elpd``           leave-one-trial-out ELPD: Laplace PSIS-LOO, tables, paired differences
``settings``       :class:`~pmabayes.criticism.settings.DiagnoseSettings`
``refits``         the diagnosed model at its MAP, the refits and the missing effect
``results``        what a diagnosis finds, and its JSON
``prose``          the verdict and the explanations in words
``diagnosis``      ``diagnose``, a short sequence of the steps above
``discrepancy``    the missing force estimated from the data (a package)
``compare``        fits of the same data side by side
``yardsticks``     the yardsticks, one class each: linear output-error, Prandtl-Ishlinskii,
                   polynomial NARX (a package)
``baselines``      the yardsticks fitted to training data and scored on an experiment
``inadequacy``     the model's discrepancy learnt from its training residual
``validation``     predictions of held-out experiments
=================  ==================================================================
"""

from pmabayes.criticism.adequacy import (
    ENERGY_TOLERANCE,
    Adequacy,
    check_adequacy,
    is_adequate,
)
from pmabayes.criticism.bands import (
    DEFAULT_BANDS_HZ,
    EXCITED_POWER_FRACTION,
    MIN_BINS,
    BandError,
    BandErrors,
    band_errors,
    band_label,
    band_rms,
    excited_band,
    floor_ratio,
    input_bands,
    instantaneous_frequency,
    power_spectrum,
)
from pmabayes.criticism.baselines import Baselines, fit_baselines
from pmabayes.criticism.compare import FitComparison, compare_fits
from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.discrepancy import (
    STATES,
    Discrepancy,
    Proposal,
    StateEvidence,
    Term,
    estimate_discrepancy,
    force_response,
    stlsq,
)
from pmabayes.criticism.inadequacy import Inadequacy, learn_inadequacy
from pmabayes.criticism.plausibility import implausible, plausible_range
from pmabayes.criticism.results import Diagnosis, ExperimentDiagnosis, Finding, Refit
from pmabayes.criticism.scores import EffectEvidence, rank_effects, significance_threshold
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.criticism.signature import Signature, residual_signature
from pmabayes.criticism.validation import (
    DEFAULT_DRAWS,
    NOISE_NAMES,
    ExperimentValidation,
    Validation,
    ValidationError,
    validate,
)
from pmabayes.criticism.whiteness import (
    NoiseModelCheck,
    WhitenessCurves,
    autocorrelation,
    check_noise_model,
    cross_correlation,
    innovations,
    judged_whiteness,
    ljung_box,
    whiteness_curves,
    whiteness_statistics,
)
from pmabayes.inference.likelihood import LEVEL_ADEQUATE, MAX_AR_ORDER

__all__ = [
    "Adequacy",
    "BandError",
    "BandErrors",
    "Baselines",
    "DEFAULT_BANDS_HZ",
    "DEFAULT_DRAWS",
    "DiagnoseSettings",
    "Diagnosis",
    "Discrepancy",
    "ENERGY_TOLERANCE",
    "EXCITED_POWER_FRACTION",
    "EffectEvidence",
    "ExperimentDiagnosis",
    "ExperimentValidation",
    "Finding",
    "FitComparison",
    "Inadequacy",
    "LEVEL_ADEQUATE",
    "MAX_AR_ORDER",
    "MIN_BINS",
    "NOISE_NAMES",
    "NoiseModelCheck",
    "Proposal",
    "Refit",
    "STATES",
    "Signature",
    "StateEvidence",
    "Term",
    "Validation",
    "ValidationError",
    "WhitenessCurves",
    "autocorrelation",
    "band_errors",
    "band_label",
    "band_rms",
    "check_adequacy",
    "check_noise_model",
    "compare_fits",
    "cross_correlation",
    "diagnose",
    "estimate_discrepancy",
    "excited_band",
    "fit_baselines",
    "floor_ratio",
    "force_response",
    "implausible",
    "innovations",
    "input_bands",
    "instantaneous_frequency",
    "is_adequate",
    "judged_whiteness",
    "learn_inadequacy",
    "ljung_box",
    "plausible_range",
    "power_spectrum",
    "rank_effects",
    "residual_signature",
    "significance_threshold",
    "stlsq",
    "validate",
    "whiteness_statistics",
    "whiteness_curves",
]
