"""A data-driven discrepancy: the missing force, estimated from the data, and a closed form.

:func:`~pmabayes.criticism.diagnosis.diagnose` calls
:func:`~pmabayes.criticism.discrepancy.estimate.estimate_discrepancy` when its verdict is
"above the floor, no candidate in the library accounts for it".

Method
------
Around the MAP trajectory the residual ``r`` (trial mean minus model) is, to first
order,

    r = J dtheta + sum_j w_j G[phi_j(states)] + noise,

where ``J`` holds the output's sensitivities to the model's free parameters (finite
differences of the simulator) and ``G[f]`` is the output's response to an extra force
``f(t)`` on the left of the equation of motion, the model linearised along its
trajectory (a small compiled linear time-varying simulation: mass, damping and
stiffness with the force effects' derivatives, and the Bouc-Wen force's own
linearisation ``dz' = kz dv + bz dz``). The basis ``phi_j`` is additive in the
states: cubic B-splines in position, velocity, pressure and the hysteretic force
``z``, the direction of motion ``sgn v``, one slow memory state (the velocity
low-passed with a time constant chosen by the evidence) and one loop state (Dahl's
friction model, ``h' = (sgn x' - h) |x'| / width``: a second hysteresis loop, its
width chosen by the evidence). Each spline block has a
second-difference roughness penalty whose weight is chosen by the evidence (type-II
maximum likelihood of the linear Gaussian model), so the flexible force does not
absorb the noise. Everything is whitened by the likelihood's own noise model
(:meth:`pmabayes.inference.likelihood.Likelihood.whiten`), so the regression is generalised
least squares.

The evidence for each state is the leave-one-trial-out ELPD lost when its terms are
dropped: the flexible force is refitted to the mean of the other trials and scored
on the left-out trial with the likelihood's per-trial density
(:meth:`~pmabayes.inference.likelihood.Likelihood.pointwise`).

The closed form is a sparse regression (sequentially thresholded least squares, as
SINDy's STLSQ) over a dictionary of named physical terms, each with its unit; the
threshold is chosen by the same leave-one-trial-out ELPD. When no closed form comes
near the flexible estimate, the flexible shape in one writable state is proposed as
a tabulated effect with one amplitude. The proposal is written as a ready user effect
(a ``.py`` file for ``--plugin``) and checked by a real nonlinear refit
(Gauss-Newton on the whitened residual, through the simulator).

Terms in ``(x, v, p)`` are written as plain force effects; a term in ``z`` as a force
effect that reads ``z`` (``reads_z``), and the memory and loop terms as ones with a
state of their own, advanced exactly over each step, whose time constant
(``tau_memory``) or width (``w_loop``) is a parameter the refit adjusts.

Before a force is proposed, errors of the position reading (a gain, a drift of its
zero, a delay, backlash; :mod:`.reading`) are fitted in its place: when they predict
left-out trials as well as the flexible force, the verdict says the missing piece is
not a force and no force is proposed.

The package's files: :mod:`.response` (the linearised model), :mod:`.linalg` (compiled
linear algebra), :mod:`.problem` (the whitened linear problem and the force's blocks),
:mod:`.regression` (penalised fits, evidence, leave-one-trial-out scores, STLSQ),
:mod:`.dictionary` (the named terms), :mod:`.reading` (errors of the reading
instead of a force), :mod:`.plugin` (the effect's file, from a
template), :mod:`.verify` (the nonlinear refit with it), :mod:`.results` and
:mod:`.estimate` (the estimate itself).
"""

from pmabayes.criticism.discrepancy.dictionary import Term
from pmabayes.criticism.discrepancy.estimate import estimate_discrepancy
from pmabayes.criticism.discrepancy.problem import MEMORY_TAUS_S, STATES, WRITABLE
from pmabayes.criticism.discrepancy.regression import stlsq
from pmabayes.criticism.discrepancy.response import force_response
from pmabayes.criticism.discrepancy.results import Discrepancy, Proposal, StateEvidence

__all__ = ["StateEvidence", "Term", "Proposal", "Discrepancy", "estimate_discrepancy",
           "force_response", "stlsq", "STATES", "MEMORY_TAUS_S", "WRITABLE"]
