"""Penalised and sparse regression on the linear problem: the flexible force with its
penalty weights by the evidence, leave-one-trial-out scores, and sequentially
thresholded least squares (SINDy's STLSQ) with its supports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmabayes.criticism.discrepancy.linalg import (
    a_b,
    at_b,
    cholesky,
    orthonormal,
    solve_lower,
    spd_solve,
)
from pmabayes.criticism.discrepancy.problem import LinearProblem

__all__ = ["stlsq"]


_LOG_LAMBDAS = np.arange(-4.0, 9.01, 1.0)


def stlsq(a: np.ndarray, b: np.ndarray, threshold: float, *, keep=(), ridge: float = 1e-8,
          max_iter: int = 20) -> np.ndarray:
    """Sequentially thresholded least squares (SINDy's STLSQ) on normalised columns.

    Least squares, then coefficients below ``threshold`` (on columns scaled to unit
    norm) are set to zero and the rest refitted, until the support stops changing;
    the last fit is unbiased (plain least squares on the support).

    Parameters
    ----------
    a : numpy.ndarray
        ``(n, k)`` design.
    b : numpy.ndarray
        ``(n,)`` target.
    threshold : float
        Smallest magnitude kept, in the units of ``b`` per unit-norm column.
    keep : iterable of int
        Columns never thresholded (the model's own parameters).
    ridge : float
        Ridge weight of the normalised problem, for near-collinear columns.
    max_iter : int
        Thresholding rounds at most.

    Returns
    -------
    numpy.ndarray
        ``(k,)`` coefficients of the original columns, zeros off the support.
    """
    norms = np.linalg.norm(a, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    an = a / norms
    gram, rhs = at_b(an, an), at_b(an, b)  # every round works on the normal equations
    kept = np.isin(np.arange(a.shape[1]), [int(k) for k in keep])
    support = np.ones(a.shape[1], dtype=bool)
    w = np.zeros(a.shape[1])
    for _ in range(int(max_iter)):
        idx = np.flatnonzero(support)
        w = np.zeros(a.shape[1])
        w[idx] = spd_solve(gram[np.ix_(idx, idx)] + ridge * np.eye(idx.size), rhs[idx])
        new = (np.abs(w) >= threshold) | kept
        if np.array_equal(new, support):
            break
        support = new
    idx = np.flatnonzero(support)
    w = np.zeros(a.shape[1])
    if idx.size:
        w[idx] = spd_solve(gram[np.ix_(idx, idx)] + 1e-12 * np.eye(idx.size), rhs[idx])
    return w / norms


@dataclass
class PenalisedFit:
    """A penalised fit: coefficients of J and of each block, the evidence, the residual."""

    blocks: list
    log_lambda: np.ndarray
    coef: np.ndarray
    cov: np.ndarray
    log_evidence: float
    energy: float


def _design(problem: LinearProblem, blocks: list) -> tuple[np.ndarray, list]:
    cols = [problem.j_w] + [b.white for b in blocks]
    sizes = [problem.j_w.shape[1]] + [b.white.shape[1] for b in blocks]
    return np.concatenate(cols, axis=1), sizes


def _precision(sizes: list, blocks: list, log_lambda: np.ndarray) -> np.ndarray:
    p = np.zeros((sum(sizes), sum(sizes)))
    k = sizes[0]
    p[:k, :k] = 1e-6 * np.eye(k)  # the model's parameters: effectively flat
    for b, s, ll in zip(blocks, sizes[1:], log_lambda, strict=True):
        p[k:k + s, k:k + s] = 10.0**ll * b.penalty
        k += s
    return p


def _log_evidence(ata, atb, btb, sizes, blocks, log_lambda, logdets) -> float:
    prec = _precision(sizes, blocks, log_lambda)
    q = ata + prec
    c = cholesky(q)
    if not np.all(np.isfinite(np.diag(c))):
        return -np.inf
    u = solve_lower(c, atb[:, None])[:, 0]
    prior = sum(s * ll * math.log(10.0) + ld
                for s, ll, ld in zip(sizes[1:], log_lambda, logdets, strict=True))
    return float(-0.5 * (btb - u @ u) - np.sum(np.log(np.diag(c))) + 0.5 * prior)


def fit_blocks(problem: LinearProblem, blocks: list, log_lambda=None) -> PenalisedFit:
    """Penalised GLS; each block's penalty weight by the evidence unless given."""
    a, sizes = _design(problem, blocks)
    ata, atb, btb = at_b(a, a), at_b(a, problem.r_w), float(problem.r_w @ problem.r_w)
    logdets = [float(np.linalg.slogdet(b.penalty)[1]) for b in blocks]
    if log_lambda is None:
        ll = np.full(len(blocks), 2.0)
        best = _log_evidence(ata, atb, btb, sizes, blocks, ll, logdets)
        for _ in range(3):  # coordinate ascent over a grid
            before = best
            for i in range(len(blocks)):
                for cand in _LOG_LAMBDAS:
                    trial = ll.copy()
                    trial[i] = cand
                    e = _log_evidence(ata, atb, btb, sizes, blocks, trial, logdets)
                    if e > best:
                        best, ll = e, trial
            if best - before < 1e-3:
                break
    else:
        ll = np.asarray(log_lambda, dtype=float)
        best = _log_evidence(ata, atb, btb, sizes, blocks, ll, logdets)
    q = ata + _precision(sizes, blocks, ll)
    cov = spd_solve(q, np.eye(q.shape[0]))
    coef = cov @ atb
    res = problem.r_w - a_b(a, coef)
    return PenalisedFit(list(blocks), ll, coef, cov, best, float(res @ res))


def correction(problem: LinearProblem, blocks: list, coef: np.ndarray) -> np.ndarray:
    """The model output's change, unwhitened: J dtheta + sum of block responses."""
    cols = [problem.j] + [b.response for b in blocks]
    return a_b(np.concatenate(cols, axis=1), coef)


def loo_scores(problem: LinearProblem, blocks: list, log_lambda, extra=None) -> np.ndarray:
    """Leave-one-trial-out log density of each trial with the given terms refitted; for a
    record without repeats, of each fold of its stretches left out
    (:meth:`LinearProblem.folds`).

    ``extra``: unpenalised columns (a closed form) as ``(white, raw, index)``: the
    whitened and unwhitened responses of the whole dictionary and the columns used.
    """
    lik, r = problem.lik, problem.r_trials
    parts = [problem.j_w] + [b.white for b in blocks]
    raws = [problem.j] + [b.response for b in blocks]
    sizes = [p.shape[1] for p in parts]
    prec = _precision(sizes, blocks, log_lambda)
    sel = [slice(None)] * len(parts)
    if extra is not None:
        ew, er, idx = extra
        parts.append(ew)
        raws.append(er[:, idx])
        sel.append(list(idx))
        k = prec.shape[0]
        p2 = np.zeros((k + len(idx),) * 2)
        p2[:k, :k] = prec
        p2[k:, k:] = 1e-8 * np.eye(len(idx))
        prec = p2
    if problem.by_stretches:
        return _stretch_scores(problem, parts, sel, prec)
    targets = problem.loo_targets()
    gram = np.block([[problem.gram(u, v)[np.ix_(_ix(su, u), _ix(sv, v))]
                      for v, sv in zip(parts, sel, strict=True)]
                     for u, su in zip(parts, sel, strict=True)])
    rhs = np.concatenate([problem.gram(u, targets)[_ix(su, u)]
                          for u, su in zip(parts, sel, strict=True)])
    c2 = (r - 1.0) / r  # the mean of r - 1 trials: its whitening scales by sqrt((r-1)/r)
    coef = spd_solve(c2 * gram + prec, c2 * rhs)  # (k, r)
    preds = problem.x0[None, :] + a_b(np.concatenate(raws, axis=1), coef).T
    nz = problem.noise
    return np.diag(lik.pointwise(preds, nz.sigma, nz.rho, nz.white)).copy()


def _ix(sel, arr: np.ndarray) -> np.ndarray:
    return np.arange(arr.shape[1])[sel]


def _stretch_scores(problem: LinearProblem, parts: list, sel: list, prec: np.ndarray
                    ) -> np.ndarray:
    """Leave-one-fold-out scores of a record without repeats: the terms refitted on the
    whitened residual of the other folds, the left-out fold scored by its
    whitened residual's Gaussian log density (the noise's own terms, the same for every
    set of terms, left out)."""
    r = problem.r_w_col
    ix = [_ix(su, u) for u, su in zip(parts, sel, strict=True)]
    gram = np.block([[problem.gram(u, v)[np.ix_(iu, iv)] for v, iv in zip(parts, ix, strict=True)]
                     for u, iu in zip(parts, ix, strict=True)])
    rhs = np.concatenate([problem.gram(u, r)[iu] for u, iu in zip(parts, ix, strict=True)])
    fold_gram = np.concatenate([np.concatenate(
        [problem.fold_gram(u, v)[:, iu][:, :, iv] for v, iv in zip(parts, ix, strict=True)],
        axis=2) for u, iu in zip(parts, ix, strict=True)], axis=1)
    fold_rhs = np.concatenate([problem.fold_gram(u, r)[:, iu]
                               for u, iu in zip(parts, ix, strict=True)], axis=1)
    design = np.concatenate([u[:, iu] for u, iu in zip(parts, ix, strict=True)], axis=1)
    out = np.empty(len(problem.folds()))
    for k, f in enumerate(problem.folds()):
        coef = spd_solve(gram - fold_gram[k] + prec, rhs - fold_rhs[k])
        e = problem.r_w[f] - a_b(design[f], coef)[:, 0]
        out[k] = -0.5 * float(e @ e)
    return out


def stlsq_path(a: np.ndarray, b: np.ndarray, k0: int, max_terms: int = 4) -> set:
    """Supports (at most ``max_terms`` terms) along STLSQ's threshold path."""
    out = set()
    dense = stlsq(a, b, 0.0, keep=range(k0), ridge=1e-3)
    mags = np.abs(dense[k0:]) * np.linalg.norm(a[:, k0:], axis=0)
    for thr in np.geomspace(max(mags.max(), 1e-12) * 1e-3, max(mags.max(), 1e-12), 40):
        w = stlsq(a, b, thr, keep=range(k0), ridge=1e-3)
        support = tuple(int(j) for j in np.flatnonzero(w[k0:]))
        if 0 < len(support) <= max_terms:
            out.add(support)
    return out


def forward_path(j: np.ndarray, cols: np.ndarray, b: np.ndarray, max_terms: int = 4) -> set:
    """Supports of greedy forward selection (each step the term removing most energy)."""
    q = orthonormal(j)
    r = b - a_b(q, at_b(q, b))
    c = cols - a_b(q, at_b(q, cols))
    cc, cr = at_b(c, c), at_b(c, r)
    chosen, out = [], set()
    for _ in range(max_terms):
        best, gain = None, -1.0
        for k in range(c.shape[1]):
            if k in chosen:
                continue
            ix = [*chosen, k]
            g = cr[ix]
            try:
                coef = spd_solve(cc[np.ix_(ix, ix)] + 1e-10 * np.eye(len(ix)), g)
            except np.linalg.LinAlgError:
                continue
            if g @ coef > gain:
                best, gain = k, float(g @ coef)
        if best is None:
            break
        chosen.append(best)
        out.add(tuple(sorted(chosen)))
    return out
