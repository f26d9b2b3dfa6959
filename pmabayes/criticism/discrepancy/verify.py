"""The check of a written proposal: the model refitted with it, through the simulator
(Levenberg-Marquardt on the whitened residual), and what it achieves.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pmabayes.criticism.discrepancy.linalg import at_b, spd_solve
from pmabayes.criticism.discrepancy.problem import LinearProblem
from pmabayes.criticism.observed import simulate_states
from pmabayes.criticism.signature import residual_signature
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.effects import load_plugin
from pmabayes.model.model import Model

#: Levenberg-Marquardt iterations at most: a state's scale (the memory's time constant)
#: trades with the coefficients and needs more than the 12 once used (a Maxwell element:
#: 3.3x the floor after 12, 1.03x after 40)
MAX_ITERATIONS = 40


def verify_proposal(problem: LinearProblem, path: Path, chosen: list,
                    n_iter: int = MAX_ITERATIONS) -> dict:
    """Refit the model with the written effect: Gauss-Newton on the whitened residual.

    The file is loaded as ``--plugin`` would, but its effect is not registered: it is
    only tried.

    Parameters
    ----------
    problem : LinearProblem
        The diagnosed model's linear problem (its data, noise and MAP).
    path : Path
        The written effect's file.
    chosen : list of (Term, float)
        Its terms and their coefficients (the refit's start).
    n_iter : int
        Levenberg-Marquardt iterations at most.

    Returns
    -------
    dict
        ``{"rms_m", "ratio", "energy", "ljung_box_p", "adequate", "values"}`` of the
        refitted model (``values``: the effect's parameters).
    """
    eff = load_plugin(path, register=False).ProposedEffect
    model = problem.model.with_effects(eff)
    lik = Likelihood(model, problem.dataset, substeps=problem.lik.substeps)
    start = {k: v for k, v in problem.values.items() if k in model.parameter_names}
    # the coefficients; a period parameter after them starts at its default
    start.update({p.name: c for p, (_, c) in zip(eff.parameters, chosen, strict=False)})
    values = _gauss_newton(problem, lik, model, start, n_iter)
    sim, trials = simulate_states(lik, model, values, problem.start, lik.substeps)
    sig = residual_signature(lik, problem.noise, sim, model_trials_m=trials)
    return {"rms_m": sig.bands[-1].rms_m, "ratio": sig.ratio, "energy": sig.energy,
            "ljung_box_p": sig.ljung_box_p, "adequate": bool(sig.is_adequate()),
            "values": {p.name: values[p.name] for p in eff.parameters}}


def _gauss_newton(problem: LinearProblem, lik: Likelihood, model: Model, start: dict,
                  n_iter: int) -> dict:
    """Levenberg-Marquardt on the whitened residual of the trial mean, within the bounds."""
    names = list(model.free_names)
    theta = model.theta(start)[0]
    idx = [model.index(n) for n in names]
    lo = np.array([model.parameter(n).bounds[0] for n in names])
    hi = np.array([model.parameter(n).bounds[1] for n in names])
    whiten = problem.whiten

    def cost(th):
        x = problem.simulate(th[None], lik)[0]
        r = whiten(lik.y_mean - x)
        return float(r @ r), r, x

    defaults = np.abs([model.parameter(n).default for n in names])
    c0, r0, _ = cost(theta)
    mu = 1e-3
    for _ in range(n_iter):
        before = c0
        h = 1e-6 * np.maximum(np.maximum(np.abs(theta[idx]), defaults), 1e-6)
        h = np.where(theta[idx] + h > hi, -h, h)  # step inward from an upper bound
        rows = np.repeat(theta[None], len(idx) + 1, axis=0)
        for k, j in enumerate(idx):
            rows[k + 1, j] += h[k]
        xs = problem.simulate(rows, lik)
        jw = np.stack([whiten((xs[k + 1] - xs[0]) / h[k]) for k in range(len(idx))], axis=1)
        norms = np.linalg.norm(jw, axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        jn = jw / norms
        ata, atb = at_b(jn, jn), at_b(jn, r0)
        improved = False
        for _ in range(8):
            # a parameter the output does not see (at a bound, a vanishing term) has a
            # zero column: the identity term keeps the damped system definite
            damped = ata + mu * np.diag(np.diag(ata)) + 1e-9 * np.eye(len(idx))
            try:
                step = spd_solve(damped, atb) / norms
            except np.linalg.LinAlgError:
                mu *= 10.0
                continue
            trial = theta.copy()
            trial[idx] = np.clip(theta[idx] + step, lo, hi)
            c1, r1, _ = cost(trial)
            if c1 < c0:
                theta, c0, r0 = trial, c1, r1
                mu = max(mu / 10.0, 1e-9)
                improved = True
                break
            mu *= 10.0
        if not improved or before - c0 < 1e-6 * c0:
            break
    return {n: float(theta[model.index(n)]) for n in model.parameter_names}
