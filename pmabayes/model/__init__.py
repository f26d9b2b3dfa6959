"""The model layer: parameters and priors, the physical effects, the model on its rig, and
its batched compiled simulator.
"""

# Each module's public names, re-exported (numpy's idiom: the lists are kept once, in
# the modules).
from pmabayes.model import effects as _effects
from pmabayes.model import model as _model
from pmabayes.model import parameters as _parameters
from pmabayes.model import simulator as _simulator
from pmabayes.model.effects import *  # noqa: F403
from pmabayes.model.model import *  # noqa: F403
from pmabayes.model.parameters import *  # noqa: F403
from pmabayes.model.simulator import *  # noqa: F403

__all__ = [*_effects.__all__, *_model.__all__, *_parameters.__all__, *_simulator.__all__]
