"""Forward regression with orthogonal least squares (FROLS) of a polynomial NARX model:
the candidate terms, their regression matrix, the error reduction ratio that ranks them,
and the free-run simulation of the terms kept.

Chen, Billings & Luo (1989), "Orthogonal least squares methods and their application to
non-linear system identification", Int. J. Control 50(5), 1873-1896; Billings (2013),
*Nonlinear System Identification: NARMAX Methods in the Time, Frequency, and
Spatio-Temporal Domains*, Wiley, ch. 3.

A term is coded as SysIdentPy codes it, so that the fitted models' JSON keeps its names:
``0`` the constant, ``1000 + j`` the output ``y(k-j)``, ``2000 + j`` the input
``u(k-j)``, ``3001`` the load (a second input, one lag); a term of degree 2 is a pair of
codes, the larger first (``[2001, 1001]``: ``u(k-1)*y(k-1)``).
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np

__all__ = ["regressor_codes", "regressors", "frols", "free_run"]

#: A candidate whose part orthogonal to the terms already chosen is below this share of
#: its own norm lies in their span (to rounding): it can reduce no error and is skipped.
_IN_SPAN = 1e-9


def _variables(lag: int, n_inputs: int) -> np.ndarray:
    """The codes of the lagged variables: 1, ``y(k-1..lag)``, ``u(k-1..lag)``, the load."""
    return np.array([0, *(1000 + j for j in range(1, lag + 1)),
                     *(2000 + j for j in range(1, lag + 1)), *([3001] * (n_inputs - 1))])


def regressor_codes(lag: int, n_inputs: int, degree: int) -> np.ndarray:
    """Every candidate term of degree at most ``degree``, ``(n_candidates, degree)`` codes,
    in the order of :func:`regressors`' columns."""
    pairs = list(combinations_with_replacement(range(1 + lag * 2 + n_inputs - 1), degree))
    return _variables(lag, n_inputs)[np.array(pairs)][:, ::-1]


def _lagged(x: np.ndarray, y: np.ndarray, lag: int) -> np.ndarray:
    """``(n - lag, n_variables)`` values of :func:`_variables` at the steps ``k >= lag``."""
    n = y.size
    cols = [np.ones(n - lag)]
    cols += [y[lag - j: n - j] for j in range(1, lag + 1)]
    cols += [x[lag - j: n - j, 0] for j in range(1, lag + 1)]
    cols += [x[lag - 1: n - 1, 1]] if x.shape[1] > 1 else []
    return np.stack(cols, axis=1)


def _columns(codes: np.ndarray, lag: int, n_inputs: int) -> np.ndarray:
    """The terms' codes as column indices of :func:`_lagged`."""
    where = {c: i for i, c in enumerate(_variables(lag, n_inputs).tolist())}
    return np.vectorize(where.__getitem__)(codes)


def regressors(x: np.ndarray, y: np.ndarray, codes: np.ndarray, lag: int) -> np.ndarray:
    """The regression matrix of the terms ``codes`` for the targets ``y[lag:]``: one row per
    step ``k >= lag`` of the inputs ``x`` ``(n, n_inputs)`` and output ``y`` ``(n,)``."""
    v = _lagged(x, y, lag)
    return np.prod(v[:, _columns(codes, lag, x.shape[1])], axis=2)


def frols(psi: np.ndarray, target: np.ndarray, n_terms: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``n_terms`` columns of ``psi`` that FROLS chooses, in its order, and their error
    reduction ratios.

    At each step the candidate whose part orthogonal to the terms already chosen explains
    the largest share of ``target``'s sum of squares (its error reduction ratio,
    ``(w'y)^2 / (w'w y'y)``) is chosen, and the rest are orthogonalised against it (modified
    Gram-Schmidt). A candidate in the span of the chosen ones is never chosen, so fewer
    than ``n_terms`` may come back.
    """
    w = np.array(psi, dtype=float)
    y = np.asarray(target, dtype=float)
    yy = max(float(y @ y), np.finfo(float).tiny)
    norm0 = np.linalg.norm(w, axis=0)
    free = norm0 > 0
    order, err = [], []
    for _ in range(min(n_terms, w.shape[1])):
        ww = np.einsum("ij,ij->j", w, w)
        free &= np.sqrt(ww) > _IN_SPAN * norm0
        if not free.any():
            break
        ratio = np.where(free, (w.T @ y) ** 2 / np.where(free, ww, 1.0) / yy, -np.inf)
        j = int(np.argmax(ratio))
        order.append(j)
        err.append(float(ratio[j]))
        free[j] = False
        q = w[:, j] / np.sqrt(ww[j])
        w -= np.outer(q, q @ w)
    return np.array(order, dtype=int), np.array(err)


def free_run(codes: np.ndarray, coefficients: np.ndarray, x: np.ndarray, lag: int,
             limit: float) -> np.ndarray | None:
    """The model's output driven by the inputs ``x`` ``(n, n_inputs)`` alone, its first
    ``lag`` values 0 (the scaled mean); None when it leaves ``limit`` or overflows."""
    cols = _columns(codes, lag, x.shape[1])
    theta = np.asarray(coefficients, dtype=float)
    y = np.zeros(x.shape[0])
    v = np.ones(1 + 2 * lag + x.shape[1] - 1)
    with np.errstate(all="ignore"):
        for k in range(lag, x.shape[0]):
            v[1: lag + 1] = y[k - lag: k][::-1]
            v[lag + 1: 2 * lag + 1] = x[k - lag: k, 0][::-1]
            v[2 * lag + 1:] = x[k - 1, 1:]
            y[k] = np.prod(v[cols], axis=1) @ theta
            if not abs(y[k]) < limit:  # NaN too
                return None
    return y
