"""The noise within the posterior density: the start of a noise sampled with the model (a
record without repeats, or a noise model that is not learnt from repeats) for the
search, and the periods of a record from rest referred to the model's residual at the
MAP (:func:`refer_periods`).

They work on a :class:`~pmabayes.inference.density.Posterior`, which holds the noise
package's estimates, so they live above both (no import circle).
"""

from __future__ import annotations

import numpy as np

from pmabayes.inference.density import Posterior
from pmabayes.inference.noise.repeats import _minimise_noise, group_noise

__all__ = ["refer_periods"]


def _default_noise_z(posterior: Posterior, first: int | None = None) -> np.ndarray:
    """The defaults, in unconstrained coordinates, of the columns from ``first`` on: by
    default the sampled noise parameters' (none when the noise comes from repeats)."""
    theta = np.array([[p.default for p in posterior.parameters]])
    first = posterior.n_searched if first is None else first
    return posterior.to_unconstrained(theta)[0, first:]


def _noise_start(posterior: Posterior, z: np.ndarray) -> np.ndarray:
    """``z`` with the noise sampled with the model (records without repeats, noise
    models not learnt from repeats) set to its posterior mode given the model's
    parameters in ``z``.

    The global search's cost does not depend on the noise, so it leaves the noise
    anywhere; a polish started there can stop in a mode of the noise alone (all of
    it white, or a negative correlation) far below the posterior's. The residual of
    the search's optimum is a series of the noise (plus what misfit is left): each
    noise model starts the search, over the noise coordinates only, of the posterior
    from it (:meth:`~pmabayes.inference.noise.NoiseModel.start`).
    """
    if posterior.n_searched == posterior.ndim:
        return z
    x = posterior.output(posterior.to_natural(z[None]))
    # several experiments are seen as one JointLikelihood, which splits the output
    parts = posterior.likelihood.split(x) if posterior.n_experiments > 1 else [x]
    # per sampled group, from its first experiment: (start, shift, noise model)
    starts: dict[int, tuple] = {}
    for e, (lik, xe) in enumerate(zip(posterior.likelihoods, parts, strict=True)):
        g = posterior.groups[e]
        if posterior.noise_sampled(e) and g not in starts:
            r = lik.y_mean - xe[0]
            if lik.observed is not None:  # a single record: its samples observed
                r = np.where(lik.observed[0], r, 0.0)
            starts[g] = (*lik.noise.start(r, lik.observed, lik), lik.noise)
    # the model's parameters and start stay at z's: its output, simulated once above,
    # is every evaluation's (thousands of them), not simulated again each time
    outputs = [np.atleast_2d(xe) for xe in parts]
    out = z.copy()
    # given the output, each group's noise enters only its own experiments' likelihood
    # and its own prior: the search splits into one small search per group (a few
    # hundred evaluations of one experiment each, where one search over all of them
    # took thousands of all)
    for g, (u0, shift, noise) in sorted(starts.items()):
        gcols = np.asarray(posterior.noise_columns(g))
        members = posterior.members(g)
        # the other columns' prior terms do not change in this search (one point at a
        # time): evaluated once, not at each of its thousands of points
        fixed = posterior.prior_terms(posterior.to_natural(out[None]),
                                      np.setdiff1d(np.arange(out.size), gcols))

        def neg(u: np.ndarray, gcols=gcols, members=members, fixed=fixed) -> np.ndarray:
            zz = np.repeat(out[None], np.atleast_2d(u).shape[0], axis=0)
            zz[:, gcols] = np.atleast_2d(u)
            return -posterior.log_prob_z(zz, outputs=outputs, experiments=members,
                                         prior_terms=fixed if zz.shape[0] == 1 else None)

        # a start that is not finite (a member's output is not: its simulation
        # overflowed) or another column's prior term that is not (an earlier group's
        # noise left at such a start) makes the cost inf at every point the search can
        # reach: its simplex would not leave the start in 60,000 evaluations
        stuck = not (np.all(np.isfinite(u0))
                     and all(np.all(np.isfinite(t)) for t in fixed.values()))
        found = u0 if stuck else _minimise_noise(neg, u0, shift)
        out[gcols] = noise.clip_start(found, posterior.upper[gcols])
    return out


def refer_periods(posterior: Posterior, z: np.ndarray) -> bool:
    """Learn the noise of records from rest, and of trials with their own inputs, from
    their repeats' residual at ``z``.

    Each experiment whose repeats must be referred to the model
    (:attr:`pmabayes.inference.likelihood.Likelihood.refers_to_model`: the periods of a
    record that starts from rest, or trials with their own inputs) takes its repeats
    from the residual at ``z``
    (:meth:`~pmabayes.inference.likelihood.Likelihood.refer_periods_to`), and the noise of its
    group is estimated again, its noise model chosen again as first requested.
    Other experiments keep theirs.

    Parameters
    ----------
    posterior : Posterior
        Updated in place (:meth:`~pmabayes.inference.density.Posterior.set_group_noise`).
    z : numpy.ndarray
        The point, in unconstrained coordinates ``(ndim,)``: a MAP.

    Returns
    -------
    bool
        Whether any experiment's periods were referred to the model.
    """
    liks = posterior.likelihoods
    shaken = [e for e, lik in enumerate(liks) if lik.refers_to_model]
    if not shaken:
        return False
    theta = posterior.to_natural(np.asarray(z, dtype=float)[None])
    for e in shaken:
        liks[e].refer_periods_to(posterior.simulate(theta, e)[0])
    for g in sorted({posterior.groups[e] for e in shaken}):
        members = posterior.members(g)
        est, choice = group_noise([liks[e] for e in members],
                                   posterior.noise_choices[members[0]].requested)
        posterior.set_group_noise(g, est, choice)
    return True
