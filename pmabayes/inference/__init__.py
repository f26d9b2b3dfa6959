"""Inference: the likelihood and its noise models, the checks of repeated trials, the noise
learnt from repeats, the posterior density and its construction, the fit file, the MAP
search, the emcee sampler and batches of fits.
"""

from pmabayes.inference.batch import (
    BatchError,
    BatchJob,
    BatchResult,
    dask_client,
    dataset_seed,
    fit_batch,
)
from pmabayes.inference.density import (
    Posterior,
)
from pmabayes.inference.errors import (
    ConvergenceWarning,
    FitError,
)
from pmabayes.inference.fitfile import (
    FitFileError,
    check_dataset,
    experiment_datasets,
    experiment_models,
    experiment_names,
    experiment_records,
    fit_info,
    fit_tree,
    load_fit,
    model_from_fit,
    noise_models,
    save_fit,
    set_fit_info,
)
from pmabayes.inference.likelihood import (
    GUARD_FACTOR,
    LEVEL_ADEQUATE,
    LJUNG_BOX_LAGS,
    MAX_AR_ORDER,
    NOISE_MODELS,
    NOISE_PARAMETERS,
    NOISE_SOURCES,
    ArNoise,
    JointLikelihood,
    Likelihood,
    LikelihoodError,
    NoiseChoice,
    ar1_noise,
    ar1_whiteness_of_repeats,
    ar_noise_from_repeats,
    check_noise_model_name,
    choose_noise_model,
    levinson,
    ljung_box_statistic,
    measurement_noise,
)
from pmabayes.inference.noise import (
    NoiseEstimate,
    estimate_noise,
    group_noise,
    refer_periods,
)
from pmabayes.inference.posterior import (
    build_posterior,
    experiments,
)
from pmabayes.inference.sampler import (
    FitSettings,
    fit,
)
from pmabayes.inference.search import (
    MapResult,
    find_map,
)
from pmabayes.inference.trials import (
    TrialCheck,
    TrialFinding,
    TrialWarning,
    check_trials,
    exclude_trials,
    parse_trial_ids,
)

__all__ = [
    "FitError",
    "ConvergenceWarning",
    "NOISE_PARAMETERS",
    "NOISE_SOURCES",
    "GUARD_FACTOR",
    "Likelihood",
    "JointLikelihood",
    "LikelihoodError",
    "ar1_noise",
    "measurement_noise",
    "NOISE_MODELS",
    "LEVEL_ADEQUATE",
    "MAX_AR_ORDER",
    "LJUNG_BOX_LAGS",
    "ljung_box_statistic",
    "levinson",
    "ArNoise",
    "ar_noise_from_repeats",
    "NoiseChoice",
    "check_noise_model_name",
    "ar1_whiteness_of_repeats",
    "choose_noise_model",
    "TrialWarning",
    "TrialFinding",
    "TrialCheck",
    "check_trials",
    "exclude_trials",
    "parse_trial_ids",
    "estimate_noise",
    "group_noise",
    "refer_periods",
    "NoiseEstimate",
    "Posterior",
    "fit_tree",
    "set_fit_info",
    "experiment_records",
    "experiment_names",
    "experiment_datasets",
    "experiment_models",
    "noise_models",
    "FitFileError",
    "save_fit",
    "load_fit",
    "fit_info",
    "model_from_fit",
    "check_dataset",
    "experiments",
    "build_posterior",
    "MapResult",
    "find_map",
    "FitSettings",
    "fit",
    "BatchError",
    "BatchJob",
    "BatchResult",
    "dask_client",
    "dataset_seed",
    "fit_batch",
]
