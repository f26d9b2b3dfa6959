"""Composable physical effects: one small class each, keeping its parameters, priors,
physics and meaning together.

An effect acts at one stage of the signal path (:data:`STAGES`): on the pressure
before the dead zone, as a force in the equation of motion, on the sensor's reading,
or on the Bouc-Wen law itself. :class:`Effect` is the extension point (a new effect
takes a dozen lines); :func:`register_effect` names it for the API and the command
line, and :func:`load_plugin` imports a user's file of effects. The documentation's
theory page on effects gives each stage's physics signature and the hooks the closed
loop uses.
"""

from pmabayes.model.effects._numerics import decay, power, smooth_sign
from pmabayes.model.effects.base import STAGES, Effect, EffectError
from pmabayes.model.effects.force import (
    CoulombFriction,
    CubicStiffness,
    ForceLengthMap,
    LengthStiffness,
    MaxwellCreep,
    McKibbenForce,
    PressureHysteresis,
    PressureStiffness,
    StribeckFriction,
)
from pmabayes.model.effects.hysteresis import BoucWenBaberNoori, BoucWenExponent
from pmabayes.model.effects.measurement import PositionOffset, QuadraticSensor
from pmabayes.model.effects.pressure import (
    RegulatorLag,
    RegulatorSecondOrder,
    TransportDelay,
    delay_effect,
)
from pmabayes.model.effects.registry import (
    get_effect,
    load_plugin,
    register_effect,
    registered_effects,
    resolve_effects,
)

#: The built-in effects, registered in the order the library grew (candidate lists
#: and their ties follow it).
#:
#: :meta hide-value:
BUILTIN: tuple[type[Effect], ...] = (
    RegulatorLag, TransportDelay, CoulombFriction, CubicStiffness, PressureStiffness,
    PositionOffset, StribeckFriction, McKibbenForce, RegulatorSecondOrder,
    PressureHysteresis, MaxwellCreep, BoucWenExponent, ForceLengthMap, LengthStiffness,
    BoucWenBaberNoori, QuadraticSensor,
)
for _effect in BUILTIN:
    register_effect(_effect)
del _effect

__all__ = [
    "STAGES",
    "BUILTIN",
    "Effect",
    "EffectError",
    "smooth_sign",
    "power",
    "decay",
    "register_effect",
    "registered_effects",
    "get_effect",
    "resolve_effects",
    "load_plugin",
    "delay_effect",
    *(effect.__name__ for effect in BUILTIN),
]
