"""pmabayes: Bayesian identification of pneumatic muscle actuators with Bouc-Wen hysteresis.

The package is organised as a one-way pipeline: data -> model (base physics and
composable effects) -> batched compiled simulator -> likelihood -> posterior
(density and fit file) -> sampler -> diagnostics, control and robustness ->
reports. Each stage is one module (or one small package); a lower stage never
imports a higher one. ``pmabayes.util`` and ``pmabayes.parallel`` serve them all.
"""

from pmabayes.effects import (
    Effect,
    EffectError,
    get_effect,
    register_effect,
    registered_effects,
)
from pmabayes.model import PAPER_AREA_M2, PAPER_VALUES, Model, ModelError, Rig, derive_area
from pmabayes.parameters import HalfNormal, LogNormal, Normal, Parameter, Prior, Uniform
from pmabayes.simulator import Simulation, SimulationError, simulate

__version__ = "0.1.0"

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
    "get_effect",
    "register_effect",
    "registered_effects",
    "simulate",
]
