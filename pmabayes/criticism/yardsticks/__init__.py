"""The yardsticks: black-box models fitted in seconds to the training data, predicting the
same experiments as the physics (:mod:`~pmabayes.criticism.baselines` fits them all).

==========  ==========================================================================
``base``    the interface (:class:`~pmabayes.criticism.yardsticks.base.Yardstick`,
            :class:`~pmabayes.criticism.yardsticks.base.Fitted`), the records, NRMSE
``linear``  a linear output-error model
``play``    a Prandtl-Ishlinskii model of play operators
``narx``    a polynomial NARX model (terms chosen by FROLS, built in: ``_frols``)
==========  ==========================================================================

A new yardstick is one :class:`~pmabayes.criticism.yardsticks.base.Yardstick` subclass
in a module imported here: defining it registers it in :data:`REGISTRY`.
"""

from pmabayes.criticism.yardsticks.base import (
    REGISTRY,
    TRAIN_SHARE,
    Fitted,
    LeftOut,
    PredictionFailed,
    Record,
    Yardstick,
    nrmse,
)
from pmabayes.criticism.yardsticks.linear import (
    MAX_LINEAR_ORDER,
    LinearBaseline,
    LinearYardstick,
    fit_linear,
)
from pmabayes.criticism.yardsticks.play import (
    PLAY_OPERATORS,
    PlayBaseline,
    PlayYardstick,
    fit_play,
)

# isort: split
# defined last, so registered last: the yardsticks in the order linear, play, narx
from pmabayes.criticism.yardsticks.narx import NarxBaseline, NarxYardstick, fit_narx

__all__ = ["REGISTRY", "TRAIN_SHARE", "MAX_LINEAR_ORDER", "PLAY_OPERATORS", "Fitted",
           "LeftOut", "PredictionFailed", "Record", "Yardstick", "nrmse", "LinearBaseline",
           "LinearYardstick", "fit_linear", "PlayBaseline", "PlayYardstick", "fit_play",
           "NarxBaseline", "NarxYardstick", "fit_narx"]
