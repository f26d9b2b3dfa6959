"""Curvature at a mode: central-difference Hessians from one batched evaluation, and the
Laplace covariance (measured again along its own eigenvectors where it is indefinite).
"""

from __future__ import annotations

import numpy as np


def _fd_hessian(f, u0: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Central-difference Hessian of ``f`` (batched callable) at ``u0``."""
    n = u0.size
    pts = [u0]
    for i in range(n):
        for j in range(i, n):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                u = u0.copy()
                u[i] += si * h[i]
                u[j] += sj * h[j]
                pts.append(u)
    vals = f(np.array(pts))
    hess = np.empty((n, n))
    k = 1
    for i in range(n):
        for j in range(i, n):
            pp, pm, mp_, mm = vals[k: k + 4]
            k += 4
            hess[i, j] = hess[j, i] = (pp - pm - mp_ + mm) / (4.0 * h[i] * h[j])
    return hess


def _scaled_hessian(neg_logpost, u: np.ndarray) -> np.ndarray:
    """The Hessian at ``u``, with steps of 0.2 of the curvature's length scale."""
    hd = np.abs(np.diag(_fd_hessian(neg_logpost, u, np.full(u.size, 1e-6))))
    return _fd_hessian(neg_logpost, u, 0.2 / np.sqrt(np.where(hd > 0, hd, 1.0)))


def _laplace_covariance(hess: np.ndarray, neg_logpost=None, u: np.ndarray | None = None,
                        passes: int = 2) -> np.ndarray:
    """The inverse Hessian, or a diagonal stand-in where that is not a covariance.

    A posterior whose parameters are strongly correlated has curvatures many orders
    of magnitude apart; steps along the axes measure its flattest directions with
    the rounding of its steepest, and the Hessian may come out indefinite. Given
    ``neg_logpost`` and the point ``u``, the Hessian is then measured again (up to
    ``passes`` times) along its own eigenvectors, each with steps of 0.2 of that
    direction's curvature length, where it is near the identity, before the
    diagonal stand-in (which drops the correlations) is taken.
    """
    h = hess
    for k in range(passes + 1):
        if not np.all(np.isfinite(h)):  # a step left the support: nothing to refine
            break
        try:
            cov = np.linalg.inv(h)
            np.linalg.cholesky(cov)
            return cov
        except np.linalg.LinAlgError:
            if neg_logpost is None or k == passes:
                break
        lam, vec = np.linalg.eigh(h)
        lam = np.abs(lam)
        if not lam.max() > 0:
            break
        t = vec / np.sqrt(np.maximum(lam, 1e-12 * lam.max()))  # columns: unit curvature

        def along(w: np.ndarray, t=t) -> np.ndarray:
            return neg_logpost(u + np.atleast_2d(w) @ t.T)

        hw = _fd_hessian(along, np.zeros(u.size), np.full(u.size, 0.2))
        tinv = np.linalg.inv(t)
        h = tinv.T @ hw @ tinv
    return np.diag(1.0 / np.where(np.diag(hess) > 0, np.diag(hess), 1e6))
