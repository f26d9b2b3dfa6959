"""The noise models of the likelihood, their registry and choice, and the noise learnt
from repeats.

- :mod:`~pmabayes.inference.noise.base`: :class:`NoiseModel`, the interface (parameters
  with priors, log density of residual series, whitening, draws, ``to_dict`` /
  ``from_dict``), and the registry (:func:`register_noise_model`).
- :mod:`~pmabayes.inference.noise.ar1`: AR(1) disturbance + white sensor noise, the
  default (:class:`Ar1White`), its Kalman-filter kernels.
- :mod:`~pmabayes.inference.noise.ar_repeats`: the AR(p) of the repeats
  (:class:`ArFromRepeats`, :class:`ArNoise`).
- :mod:`~pmabayes.inference.noise.student_t`: Student-t white noise, for outliers
  (:class:`StudentT`).
- :mod:`~pmabayes.inference.noise.choice`: which model a likelihood uses
  (:func:`choose_noise_model`, :class:`NoiseChoice`).
- :mod:`~pmabayes.inference.noise.repeats`: the AR(1) + white noise's posterior from the
  repeats (:func:`estimate_noise`) and each noise group's (:func:`group_noise`). The
  periods of a record from rest referred to the model
  (:func:`pmabayes.inference.noise_start.refer_periods`) work on the posterior density,
  above this package.

A new noise model is one module beside these: a :class:`NoiseModel` subclass decorated
with :func:`register_noise_model`, imported below; its ``name`` is then a value of
``noise_model``.
"""

from pmabayes.inference.noise.ar1 import (
    AR1_WHITE,
    NOISE_PARAMETERS,
    NOISE_PER_AMPLITUDE,
    Ar1White,
    ar1_noise,
    measurement_noise,
)
from pmabayes.inference.noise.ar_repeats import (
    MAX_AR_ORDER,
    ArFromRepeats,
    ArNoise,
    ar_noise_from_repeats,
    levinson,
)
from pmabayes.inference.noise.base import (
    NoiseModel,
    noise_model_class,
    register_noise_model,
    registered_noise_models,
)
from pmabayes.inference.noise.choice import (
    LEVEL_ADEQUATE,
    LJUNG_BOX_LAGS,
    NOISE_MODELS,
    NoiseChoice,
    ar1_whiteness_of_repeats,
    check_noise_model_name,
    choose_noise_model,
    ljung_box_statistic,
    noise_model_from_record,
)
from pmabayes.inference.noise.repeats import (
    NoiseEstimate,
    _lag_moment,
    _log_sech2,
    _minimise_noise,
    _moment_start,
    estimate_noise,
    group_noise,
)
from pmabayes.inference.noise.student_t import STUDENT_T_PARAMETERS, StudentT

__all__ = [
    "estimate_noise",
    "group_noise",
    "NoiseEstimate",
    "NoiseModel",
    "register_noise_model",
    "noise_model_class",
    "registered_noise_models",
    "Ar1White",
    "AR1_WHITE",
    "ArFromRepeats",
    "ArNoise",
    "StudentT",
    "NoiseChoice",
    "choose_noise_model",
    "check_noise_model_name",
    "noise_model_from_record",
    "ar1_whiteness_of_repeats",
    "ar_noise_from_repeats",
    "levinson",
    "ljung_box_statistic",
    "ar1_noise",
    "measurement_noise",
    "NOISE_PARAMETERS",
    "NOISE_PER_AMPLITUDE",
    "STUDENT_T_PARAMETERS",
    "NOISE_MODELS",
    "LEVEL_ADEQUATE",
    "LJUNG_BOX_LAGS",
    "MAX_AR_ORDER",
]

# private helpers other modules of the package's users import
_PRIVATE = (_lag_moment, _log_sech2, _minimise_noise, _moment_start)
