"""pmabayes: Bayesian identification of pneumatic muscle actuators with Bouc-Wen hysteresis.

Data flow one way through the layers, each a folder: :mod:`pmabayes.data`,
:mod:`pmabayes.model` (base physics, composable effects, the compiled simulator),
:mod:`pmabayes.inference` (likelihood, noise, posterior, sampler, fit file),
:mod:`pmabayes.criticism` (adequacy, diagnosis, validation), :mod:`pmabayes.control`
and :mod:`pmabayes.report`; a lower layer never imports a higher one
(:data:`pmabayes._layers.LAYERS`).

The model layer is imported with the package. The workflow's verbs, :func:`fit`,
:func:`diagnose`, :func:`validate` and :func:`load_fit`, are here too, imported when
first used, so that ``import pmabayes`` stays quick.
"""

import importlib

from pmabayes.model.effects import (
    Effect,
    EffectError,
    get_effect,
    register_effect,
    registered_effects,
)
from pmabayes.model.model import PAPER_AREA_M2, PAPER_VALUES, Model, ModelError, Rig, derive_area
from pmabayes.model.parameters import HalfNormal, LogNormal, Normal, Parameter, Prior, Uniform
from pmabayes.model.simulator import Simulation, SimulationError, simulate

__version__ = "0.1.0"

#: the workflow's verbs, each imported from its layer when first used
_VERBS = {
    "fit": "pmabayes.inference.sampler",
    "load_fit": "pmabayes.inference.fitfile",
    "diagnose": "pmabayes.criticism.diagnosis",
    "validate": "pmabayes.criticism.validation",
}


def __getattr__(name: str):
    if name in _VERBS:
        value = getattr(importlib.import_module(_VERBS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pmabayes' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_VERBS])


__all__ = [
    "Effect",
    "EffectError",
    "HalfNormal",
    "LogNormal",
    "Model",
    "ModelError",
    "Normal",
    "PAPER_AREA_M2",
    "PAPER_VALUES",
    "Parameter",
    "Prior",
    "Rig",
    "Simulation",
    "SimulationError",
    "Uniform",
    "derive_area",
    "diagnose",
    "fit",
    "load_fit",
    "validate",
    "get_effect",
    "register_effect",
    "registered_effects",
    "simulate",
]
