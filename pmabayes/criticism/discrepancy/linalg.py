"""Compiled linear algebra for the discrepancy's small problems: Cholesky factors,
triangular solves and products of tall matrices.

On a loaded machine, threaded BLAS and LAPACK routines spend hundreds of times longer
waiting for their threads than computing on matrices of these sizes, so these run in
compiled loops.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: the products (``at_b``, ``a_b``) and the compiled kernels (``cholesky``,
#: ``solve_lower``, ``solve_lower_transposed``) are public to the package too
__all__ = ["spd_solve", "orthonormal"]


@numba.njit(cache=True)
def cholesky(q):  # pragma: no cover
    """Lower Cholesky factor of ``q``; a NaN diagonal when ``q`` is not positive definite."""
    n = q.shape[0]
    c = np.zeros_like(q)
    for j in range(n):
        s = q[j, j]
        for k in range(j):
            s -= c[j, k] * c[j, k]
        if not s > 0.0:
            c[j, j] = np.nan
            return c
        c[j, j] = math.sqrt(s)
        for i in range(j + 1, n):
            t = q[i, j]
            for k in range(j):
                t -= c[i, k] * c[j, k]
            c[i, j] = t / c[j, j]
    return c


@numba.njit(cache=True)
def _triangular_kernel(c, b, transposed):  # pragma: no cover
    """Solve ``c x = b`` (forward) or ``c.T x = b`` (backward) for lower-triangular ``c``."""
    n, m = b.shape
    x = np.empty_like(b)
    for col in range(m):
        for step in range(n):
            i = n - 1 - step if transposed else step
            t = b[i, col]
            if transposed:
                for k in range(i + 1, n):
                    t -= c[k, i] * x[k, col]
            else:
                for k in range(i):
                    t -= c[i, k] * x[k, col]
            x[i, col] = t / c[i, i]
    return x


def solve_lower(c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``c y = b`` for lower-triangular ``c``; ``b`` is ``(n, m)``."""
    return _triangular_kernel(c, b, False)


def solve_lower_transposed(c: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Solve ``c.T x = y`` for lower-triangular ``c``; ``y`` is ``(n, m)``."""
    return _triangular_kernel(c, y, True)


@numba.njit(cache=True)
def _product_kernel(a, b, transpose_a):  # pragma: no cover
    """``a.T @ b`` (``transpose_a``) or ``a @ b``, row by row of ``a`` (one pass over it)."""
    n, k = a.shape
    m = b.shape[1]
    out = np.zeros((k, m) if transpose_a else (n, m))
    for i in range(n):
        for p in range(k):
            aip = a[i, p]
            if transpose_a:
                for j in range(m):
                    out[p, j] += aip * b[i, j]
            else:
                for j in range(m):
                    out[i, j] += aip * b[p, j]
    return out


def _columns(b: np.ndarray) -> tuple[np.ndarray, bool]:
    """``b`` as a contiguous float matrix, and whether it was a vector."""
    b = np.ascontiguousarray(b, dtype=float)
    return (b[:, None], True) if b.ndim == 1 else (b, False)


def _product(a: np.ndarray, b: np.ndarray, transpose_a: bool) -> np.ndarray:
    cols, vec = _columns(b)
    out = _product_kernel(np.ascontiguousarray(a, dtype=float), cols, transpose_a)
    return out[:, 0] if vec else out


def at_b(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a.T @ b`` in compiled loops (``a``: ``(n, k)``; ``b``: ``(n,)`` or ``(n, m)``)."""
    return _product(a, b, True)


def a_b(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` in compiled loops (``a``: ``(n, k)``; ``b``: ``(k,)`` or ``(k, m)``)."""
    return _product(a, b, False)


def spd_solve(q: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the symmetric positive definite system ``q x = b``.

    Parameters
    ----------
    q : numpy.ndarray
        ``(k, k)``, symmetric positive definite.
    b : numpy.ndarray
        ``(k,)`` or ``(k, m)``.

    Returns
    -------
    numpy.ndarray
        ``x``, shaped as ``b``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``q`` is not positive definite.
    """
    c = cholesky(np.ascontiguousarray(q, dtype=float))
    if not np.all(np.isfinite(np.diag(c))):
        raise np.linalg.LinAlgError("matrix not positive definite")
    cols, vec = _columns(b)
    x = solve_lower_transposed(c, solve_lower(c, cols))
    return x[:, 0] if vec else x


def orthonormal(j: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the columns of ``j`` (Cholesky QR).

    Parameters
    ----------
    j : numpy.ndarray
        ``(n, k)``, tall.

    Returns
    -------
    numpy.ndarray
        ``(n, k)`` with orthonormal columns spanning those of ``j``.
    """
    gram = at_b(j, j)
    gram += 1e-12 * np.trace(gram) * np.eye(gram.shape[0])
    c = cholesky(gram)
    return solve_lower(c, np.ascontiguousarray(j.T)).T
