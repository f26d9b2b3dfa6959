"""pmabayes: Bayesian identification of pneumatic muscle actuators with Bouc-Wen hysteresis.

Data flow one way through the layers, each a folder: :mod:`pmabayes.data`,
:mod:`pmabayes.model` (base physics, composable effects, the compiled simulator),
:mod:`pmabayes.inference` (likelihood, noise, posterior, sampler, fit file),
:mod:`pmabayes.criticism` (adequacy, diagnosis, validation), :mod:`pmabayes.control`
and :mod:`pmabayes.report`; a lower layer never imports a higher one
(:data:`pmabayes._layers.LAYERS`).

Every name here (the model layer's and the workflow's verbs, :func:`fit`,
:func:`diagnose`, :func:`validate` and :func:`load_fit`) is imported from its layer
when first used (PEP 562), so that ``import pmabayes`` and the command line's
``--help`` stay quick: numpy, numba and scipy load only when something needs them.
"""

import importlib

__version__ = "0.2.0"

#: each public name and the module it is imported from when first used
_LAZY = {
    **dict.fromkeys(("Effect", "EffectError", "get_effect", "register_effect",
                     "registered_effects"), "pmabayes.model.effects"),
    **dict.fromkeys(("PAPER_AREA_M2", "PAPER_VALUES", "Model", "ModelError", "Rig",
                     "derive_area"), "pmabayes.model.model"),
    **dict.fromkeys(("HalfNormal", "LogNormal", "Normal", "Parameter", "Prior", "Uniform"),
                    "pmabayes.model.parameters"),
    **dict.fromkeys(("Simulation", "SimulationError", "simulate"), "pmabayes.model.simulator"),
    "fit": "pmabayes.inference.sampler",
    "load_fit": "pmabayes.inference.fitfile",
    "diagnose": "pmabayes.criticism.diagnosis",
    "validate": "pmabayes.criticism.validation",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pmabayes' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = sorted(_LAZY)
