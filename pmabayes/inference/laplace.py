"""Curvature at a mode: central-difference Hessians from one batched evaluation, and the
Laplace covariance (measured again along its own eigenvectors where it is indefinite),
with the reason recorded wherever it is a stand-in.

Steps are chosen, never taken as given: a curvature that cannot be measured (zero, or
not finite where a probing step left the prior's support and met the ``1e300`` stand-in
of the log density) gives the probing step back, never a step of 0 (whose difference
quotient is ``0/0``), and every step is held between a floor that rounding cannot eat
and a ceiling, both scaled with ``|u|``.
"""

from __future__ import annotations

import numpy as np

#: The step, relative to ``max(1, |u|)``, that first probes each diagonal curvature (in
#: the polish's coordinates, scaled to the prior's plausible box).
PROBE_STEP = 1e-6
#: Fewest and most a step may be, relative to ``max(1, |u|)``: below the floor, ``u + h``
#: rounds back towards ``u`` and the difference is noise; above the ceiling it measures
#: the whole plausible box, not the mode.
MIN_STEP, MAX_STEP = 1e-8, 1.0
#: Steps are this share of the curvature's length scale ``1 / sqrt(curvature)``.
STEP_SHARE = 0.2


def _checked_steps(u0, h) -> tuple[np.ndarray, np.ndarray]:
    """``u0`` as floats and ``h`` broadcast to it, refused where a step is not a positive
    finite number (a step of 0 or NaN would make the Hessian NaN)."""
    u0 = np.asarray(u0, dtype=float)
    h = np.broadcast_to(np.asarray(h, dtype=float), u0.shape)
    bad = ~(np.isfinite(h) & (h > 0))
    if bad.any():
        raise ValueError(f"finite-difference steps must be positive and finite; coordinates "
                         f"{np.flatnonzero(bad).tolist()} have {h[bad].tolist()} "
                         "(choose them with pmabayes.inference.laplace.steps)")
    return u0, h


def _fd_hessian(f, u0: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Central-difference Hessian of ``f`` (batched callable) at ``u0`` with steps ``h``.

    A point where ``f`` is the ``1e300`` stand-in of a point outside the support gives an
    entry that overflows to ``inf`` (the edge, :func:`pmabayes.inference.search._open_edges`),
    never a NaN from the steps.

    Raises
    ------
    ValueError
        If a step is not a positive finite number (a step of 0 or NaN would make the
        Hessian NaN; :func:`steps` chooses them).
    """
    u0, h = _checked_steps(u0, h)
    n = u0.size
    pts = [u0]
    for i in range(n):
        for j in range(i, n):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                u = u0.copy()
                u[i] += si * h[i]
                u[j] += sj * h[j]
                pts.append(u)
    vals = np.asarray(f(np.array(pts)), dtype=float)
    hess = np.empty((n, n))
    k = 1
    with np.errstate(over="ignore"):  # overflow to inf marks a step across the edge
        for i in range(n):
            for j in range(i, n):
                pp, pm, mp_, mm = vals[k: k + 4]
                k += 4
                hess[i, j] = hess[j, i] = (pp - pm - mp_ + mm) / (4.0 * h[i] * h[j])
    return hess


def _fd_diagonal(f, u0: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The diagonal of :func:`_fd_hessian` ``(f, u0, h)``, to the bit, from its diagonal
    entries' points alone (``4 n`` evaluations instead of ``2 n (n + 1) + 1``): each
    point's value is its own arithmetic, whatever else is in the batch.

    Raises
    ------
    ValueError
        As :func:`_fd_hessian`.
    """
    u0, h = _checked_steps(u0, h)
    n = u0.size
    pts = []
    for i in range(n):
        for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):  # as _fd_hessian's (i, i)
            u = u0.copy()
            u[i] += si * h[i]
            u[i] += sj * h[i]
            pts.append(u)
    vals = np.asarray(f(np.array(pts)), dtype=float).reshape(n, 4)
    with np.errstate(over="ignore"):  # overflow to inf marks a step across the edge
        return np.array([(pp - pm - mp_ + mm) / (4.0 * h[i] * h[i])
                         for i, (pp, pm, mp_, mm) in enumerate(vals)])


def steps(curvature: np.ndarray, u: np.ndarray, probe: float = PROBE_STEP) -> np.ndarray:
    """Central-difference steps of :data:`STEP_SHARE` of each coordinate's curvature
    length, never 0 or NaN.

    Parameters
    ----------
    curvature : numpy.ndarray
        Each coordinate's curvature (its sign ignored) from a probing difference.
    u : numpy.ndarray
        The point.
    probe : float
        The probing step, relative to ``max(1, |u|)``: the step where the curvature is
        zero or not finite (the probe left the support, or overflowed).

    Returns
    -------
    numpy.ndarray
        Steps within ``[MIN_STEP, MAX_STEP] * max(1, |u|)``.

    Examples
    --------
    >>> steps(np.array([4.0, 0.0, np.inf, np.nan]), np.zeros(4)).tolist()
    [0.1, 1e-06, 1e-06, 1e-06]
    """
    c = np.abs(np.asarray(curvature, dtype=float))
    size = np.maximum(1.0, np.abs(np.asarray(u, dtype=float)))
    measured = np.isfinite(c) & (c > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(measured, STEP_SHARE / np.sqrt(np.where(measured, c, 1.0)), probe * size)
    return np.clip(h, MIN_STEP * size, MAX_STEP * size)


def _scaled_hessian(neg_logpost, u: np.ndarray) -> np.ndarray:
    """The Hessian at ``u``, with steps of 0.2 of the curvature's length scale
    (:func:`steps`)."""
    probe = PROBE_STEP * np.maximum(1.0, np.abs(u))
    hd = _fd_diagonal(neg_logpost, u, probe)  # the probe needs the diagonal alone
    return _fd_hessian(neg_logpost, u, steps(hd, u))


def laplace_covariance(hess: np.ndarray, neg_logpost=None, u: np.ndarray | None = None,
                       passes: int = 2) -> tuple[np.ndarray, str | None]:
    """The inverse Hessian, or a diagonal stand-in where that is not a covariance, and
    why it is a stand-in.

    A posterior whose parameters are strongly correlated has curvatures many orders
    of magnitude apart; steps along the axes measure its flattest directions with
    the rounding of its steepest, and the Hessian may come out indefinite. Given
    ``neg_logpost`` and the point ``u``, the Hessian is then measured again (up to
    ``passes`` times) along its own eigenvectors, each with steps of 0.2 of that
    direction's curvature length, where it is near the identity, before the
    diagonal stand-in (which drops the correlations) is taken. A Hessian that is not
    finite is not refined: the stand-in keeps each measured positive curvature, and
    gives a variance of ``1e-6`` (in the polish's box-scaled coordinates) where there
    is none.

    Parameters
    ----------
    hess : numpy.ndarray
        The Hessian of the negative log posterior ``(n, n)``.
    neg_logpost : callable, optional
        The batched negative log posterior, to measure again.
    u : numpy.ndarray, optional
        The mode.
    passes : int
        Measurements again along the eigenvectors, at most.

    Returns
    -------
    cov : numpy.ndarray
        ``(n, n)``, finite.
    note : str or None
        Why ``cov`` is a stand-in (not finite, or not positive definite after the
        passes), None where it is the inverse Hessian.
    """
    h = hess
    why = None
    for k in range(passes + 1):
        if not np.all(np.isfinite(h)):  # a step left the support: nothing to refine
            bad = np.flatnonzero(~np.all(np.isfinite(h), axis=1)).tolist()
            why = (f"the Hessian at the mode is not finite in coordinates {bad} (a "
                   "difference step left the prior's support)")
            break
        try:
            cov = np.linalg.inv(h)
            np.linalg.cholesky(cov)
            if np.all(np.isfinite(cov)):
                return cov, None
        except np.linalg.LinAlgError:
            pass
        why = ("the Hessian at the mode is not positive definite"
               + (f" after {k} measurement(s) again along its eigenvectors" if neg_logpost
                  is not None else " (not measured again: a coordinate is at the edge of "
                  "the prior's support)"))
        if neg_logpost is None or k == passes:
            break
        lam, vec = np.linalg.eigh(h)
        lam = np.abs(lam)
        if not lam.max() > 0:
            break
        t = vec / np.sqrt(np.maximum(lam, 1e-12 * lam.max()))  # columns: unit curvature

        def along(w: np.ndarray, t=t) -> np.ndarray:
            # a direction measured as flat has a long unit: a step along it that
            # overflows is a step out of the support, which neg_logpost answers
            with np.errstate(over="ignore", invalid="ignore"):
                return neg_logpost(u + np.atleast_2d(w) @ t.T)

        hw = _fd_hessian(along, np.zeros(u.size), np.full(u.size, STEP_SHARE))
        tinv = np.linalg.inv(t)
        with np.errstate(over="ignore", invalid="ignore"):
            # a step out of the support measured along a direction overflows here: the
            # next pass finds it not finite and takes the stand-in, with that reason
            h = tinv.T @ hw @ tinv
    d = np.diag(hess)
    ok = np.isfinite(d) & (d > 0)
    return (np.diag(1.0 / np.where(ok, d, 1e6)),
            f"{why}; a diagonal stand-in is used (correlations dropped"
            + (f", coordinates {np.flatnonzero(~ok).tolist()} given a variance of 1e-6"
               if not ok.all() else "") + ")")


def _laplace_covariance(hess: np.ndarray, neg_logpost=None, u: np.ndarray | None = None,
                        passes: int = 2) -> np.ndarray:
    """:func:`laplace_covariance` without its note."""
    return laplace_covariance(hess, neg_logpost, u, passes)[0]
