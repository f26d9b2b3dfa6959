"""A data-driven discrepancy: the missing force, estimated from the data, and a closed form.

Stage 7 (diagnostics), beside :mod:`pmabayes.criticism.diagnosis`, whose :func:`~pmabayes.criticism.diagnosis.diagnose`
calls :func:`estimate_discrepancy` when its verdict is "above the floor, no candidate in
the library accounts for it".

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
``z``, the direction of motion ``sgn v``, and one slow memory state (the velocity
low-passed with a time constant chosen by the evidence). Each spline block has a
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
effect that reads ``z`` (``reads_z``), and the memory term as one with a state of its
own, the low-passed velocity, advanced exactly over each step.
"""

from __future__ import annotations

import importlib.util
import math
import re
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numba
import numpy as np
from scipy.interpolate import BSpline, PPoly

from pmabayes.criticism.residuals import band_errors, residual_signature
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.model import Model
from pmabayes.model.simulator import Simulation, simulate_dataset

__all__ = ["StateEvidence", "Term", "Proposal", "Discrepancy", "estimate_discrepancy",
           "force_response", "stlsq", "STATES"]

#: the states the flexible force may depend on: name, unit, symbol
STATES = (("position", "m", "x"), ("velocity", "m/s", "v"), ("pressure", "Pa", "p"),
          ("hysteresis", "N", "z"), ("direction", "1", "sgn v"),
          ("memory", "m/s", "v_lp"))
#: spline basis functions per state (position resolves detents of ~4 knot spacings)
_N_BASIS = {"position": 64, "velocity": 16, "pressure": 12, "hysteresis": 12, "memory": 12}
#: time constants scanned for the memory state (low-passed velocity), s
MEMORY_TAUS_S = (0.1, 0.4, 1.6)
#: states a force effect can be written in today (force-stage physics gets x, v, p)
WRITABLE = ("position", "velocity", "pressure")
_LOG_LAMBDAS = np.arange(-4.0, 9.01, 1.0)


# ---------------------------------------------------------------------------------
# the linearised model: the output's response to an extra force


@numba.njit(cache=True)
def _ltv_kernel(mass, damp, stiff, kz, bz, forces, dt, substeps, out):  # pragma: no cover
    """Position response of the linearised plant to forces ``(k, n)`` (trapezoidal rule)."""
    n = damp.size
    h = dt / substeps
    m0 = np.empty((n, 3, 3))
    m1i = np.empty((n, 3, 3))
    a = np.zeros((3, 3))
    for k in range(n - 1):
        c = 0.5 * (damp[k] + damp[k + 1])
        kk = 0.5 * (stiff[k] + stiff[k + 1])
        az = 0.5 * (kz[k] + kz[k + 1])
        bb = 0.5 * (bz[k] + bz[k + 1])
        a[0, 1] = 1.0
        a[1, 0] = -kk / mass
        a[1, 1] = -c / mass
        a[1, 2] = -1.0 / mass
        a[2, 1] = az
        a[2, 2] = bb
        m1 = np.eye(3) - 0.5 * h * a
        m0[k] = np.eye(3) + 0.5 * h * a
        m1i[k] = np.linalg.inv(m1)
    y = np.zeros(3)
    rhs = np.zeros(3)
    for j in range(forces.shape[0]):
        y[0] = -forces[j, 0] / stiff[0]  # the static rest shifts under a force at rest
        y[1] = 0.0
        y[2] = 0.0
        out[j, 0] = y[0]
        for k in range(n - 1):
            df = forces[j, k + 1] - forces[j, k]
            for s in range(substeps):
                f0 = forces[j, k] + df * s / substeps
                f1 = forces[j, k] + df * (s + 1) / substeps
                for r in range(3):
                    rhs[r] = m0[k, r, 0] * y[0] + m0[k, r, 1] * y[1] + m0[k, r, 2] * y[2]
                rhs[1] -= 0.5 * h * (f0 + f1) / mass
                for r in range(3):
                    y[r] = m1i[k, r, 0] * rhs[0] + m1i[k, r, 1] * rhs[1] + m1i[k, r, 2] * rhs[2]
            out[j, k + 1] = y[0]


@dataclass(frozen=True)
class _Plant:
    """The model's coefficients along its MAP trajectory, for the linear response."""

    mass: float
    damp: np.ndarray
    stiff: np.ndarray
    kz: np.ndarray
    bz: np.ndarray
    dt: float


def _plant(model: Model, values: dict, sim: Simulation, dt_s: float) -> _Plant:
    theta = model.theta({k: v for k, v in values.items() if k in model.parameter_names})[0]
    x, v = sim.true_position_m[0], sim.velocity_m_s[0]
    p, z = sim.pressure_pa[0], sim.hysteresis_n[0]
    fx, fv = np.zeros_like(x), np.zeros_like(x)
    for eff, sl in model.effect_slices():
        if eff.stage != "force":
            continue
        q = np.ascontiguousarray(theta[sl])
        for k in range(x.size):
            r = eff.physics(q, x[k], v[k], p[k])
            fx[k] += r[1]
            fv[k] += r[2]
    alpha, beta, gamma = (float(values[n]) for n in ("alpha", "beta", "gamma"))
    c = beta * np.where(v * z >= 0.0, 1.0, -1.0) + gamma
    kz = alpha - c * np.abs(z)
    bz = -v * c * np.where(z >= 0.0, 1.0, -1.0)
    return _Plant(model.rig.moving_mass_kg, float(values["d"]) + fv,
                  float(values["K_e"]) + fx, kz, bz, dt_s)


def force_response(plant: _Plant, forces_n: np.ndarray, *, substeps: int = 4) -> np.ndarray:
    """Position response of the linearised model to extra forces along its trajectory.

    Parameters
    ----------
    plant : _Plant
        The model's coefficients along its trajectory (from the diagnosis' MAP).
    forces_n : numpy.ndarray
        ``(k, n_samples)`` forces on the left of the equation of motion (opposing
        extension, as a force effect's), one per row.
    substeps : int
        Trapezoidal steps per sample interval.

    Returns
    -------
    numpy.ndarray
        ``(k, n_samples)`` change of the position, to first order in the forces.
    """
    f = np.ascontiguousarray(np.atleast_2d(forces_n), dtype=float)
    out = np.empty_like(f)
    _ltv_kernel(plant.mass, np.ascontiguousarray(plant.damp), np.ascontiguousarray(plant.stiff),
                np.ascontiguousarray(plant.kz), np.ascontiguousarray(plant.bz), f, plant.dt,
                int(substeps), out)
    return out


# ---------------------------------------------------------------------------------
# the regression pieces

# Small dense SPD systems and the products of tall matrices are computed in compiled
# loops: on a loaded machine, threaded BLAS and LAPACK routines spend hundreds of times
# longer waiting for their threads than computing on matrices of these sizes.


@numba.njit(cache=True)
def _cholesky(q):  # pragma: no cover
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
def _forward(c, b):  # pragma: no cover
    """Solve ``c y = b`` for lower-triangular ``c``; ``b`` is ``(n, m)``."""
    n, m = b.shape
    y = np.empty_like(b)
    for col in range(m):
        for i in range(n):
            t = b[i, col]
            for k in range(i):
                t -= c[i, k] * y[k, col]
            y[i, col] = t / c[i, i]
    return y


@numba.njit(cache=True)
def _backward(c, y):  # pragma: no cover
    """Solve ``c.T x = y`` for lower-triangular ``c``; ``y`` is ``(n, m)``."""
    n, m = y.shape
    x = np.empty_like(y)
    for col in range(m):
        for i in range(n - 1, -1, -1):
            t = y[i, col]
            for k in range(i + 1, n):
                t -= c[k, i] * x[k, col]
            x[i, col] = t / c[i, i]
    return x


@numba.njit(cache=True)
def _at_b_kernel(a, b):  # pragma: no cover
    n, k = a.shape
    m = b.shape[1]
    out = np.zeros((k, m))
    for i in range(n):
        for p in range(k):
            aip = a[i, p]
            for j in range(m):
                out[p, j] += aip * b[i, j]
    return out


@numba.njit(cache=True)
def _a_b_kernel(a, b):  # pragma: no cover
    n, k = a.shape
    m = b.shape[1]
    out = np.zeros((n, m))
    for i in range(n):
        for p in range(k):
            aip = a[i, p]
            for j in range(m):
                out[i, j] += aip * b[p, j]
    return out


def _at_b(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a.T @ b`` in compiled loops (``b``: vector or matrix)."""
    vec = b.ndim == 1
    out = _at_b_kernel(np.ascontiguousarray(a, dtype=float),
                       np.ascontiguousarray(b[:, None] if vec else b, dtype=float))
    return out[:, 0] if vec else out


def _a_b(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` in compiled loops (``b``: vector or matrix)."""
    vec = b.ndim == 1
    out = _a_b_kernel(np.ascontiguousarray(a, dtype=float),
                      np.ascontiguousarray(b[:, None] if vec else b, dtype=float))
    return out[:, 0] if vec else out


def _spd_solve(q: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the symmetric positive definite system ``q x = b`` (``b``: vector or matrix)."""
    c = _cholesky(np.ascontiguousarray(q, dtype=float))
    if not np.all(np.isfinite(np.diag(c))):
        raise np.linalg.LinAlgError("matrix not positive definite")
    bb = np.ascontiguousarray(b, dtype=float)
    vec = bb.ndim == 1
    bb = bb[:, None] if vec else bb
    x = _backward(c, _forward(c, np.ascontiguousarray(bb)))
    return x[:, 0] if vec else x



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
    gram, rhs = _at_b(an, an), _at_b(an, b)  # every round works on the normal equations
    kept = np.isin(np.arange(a.shape[1]), [int(k) for k in keep])
    support = np.ones(a.shape[1], dtype=bool)
    w = np.zeros(a.shape[1])
    for _ in range(int(max_iter)):
        idx = np.flatnonzero(support)
        w = np.zeros(a.shape[1])
        w[idx] = _spd_solve(gram[np.ix_(idx, idx)] + ridge * np.eye(idx.size), rhs[idx])
        new = (np.abs(w) >= threshold) | kept
        if np.array_equal(new, support):
            break
        support = new
    idx = np.flatnonzero(support)
    w = np.zeros(a.shape[1])
    if idx.size:
        w[idx] = _spd_solve(gram[np.ix_(idx, idx)] + 1e-12 * np.eye(idx.size), rhs[idx])
    return w / norms


def _orthonormal(j: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the columns of ``j`` (Cholesky QR)."""
    gram = _at_b(j, j)
    gram += 1e-12 * np.trace(gram) * np.eye(gram.shape[0])
    c = _cholesky(gram)
    return _forward(c, np.ascontiguousarray(j.T)).T


def _bspline_design(s: np.ndarray, n_basis: int, lo: float, hi: float) -> np.ndarray:
    inner = np.linspace(lo, hi, n_basis - 2)
    t = np.concatenate([[lo] * 3, inner, [hi] * 3])
    return BSpline.design_matrix(np.clip(s, lo, hi), t, 3).toarray(), t


def _low_pass(v: np.ndarray, tau_s: float, dt_s: float) -> np.ndarray:
    a = math.exp(-dt_s / tau_s)
    out = np.empty_like(v)
    acc = 0.0
    for k in range(v.size):
        acc = a * acc + (1.0 - a) * v[k]
        out[k] = acc
    return out


@dataclass
class _Block:
    """One state's columns: the force basis along the trajectory and its response."""

    state: str
    basis: np.ndarray          # (n, k) force basis along the trajectory, N per coefficient
    penalty: np.ndarray        # (k, k)
    white: np.ndarray = None   # (n, k) whitened responses, scaled
    response: np.ndarray = None  # (n, k) unwhitened responses, scaled
    scale: float = 1.0
    knots: np.ndarray | None = None
    grid: tuple | None = None  # (lo, hi) of the state


def _second_difference(k: int) -> np.ndarray:
    d = np.diff(np.eye(k), n=2, axis=0)
    return d.T @ d + 1e-6 * np.eye(k)


class _Problem:
    """The whitened linear problem around the MAP: residual, sensitivities, force blocks."""

    def __init__(self, likelihood: Likelihood, noise, values: dict, sim: Simulation) -> None:
        self.lik = likelihood
        self._gram: dict = {}
        self._targets = None
        self.noise = noise
        self.values = values
        self.sim = sim
        self.model = likelihood.model
        self.dataset = likelihood.dataset
        self.x0 = sim.position_m[0]
        self.n = self.x0.size
        self.r_trials = likelihood.n_trials
        self.plant = _plant(self.model, values, sim, self.dataset.dt_s)
        self.resid = likelihood.y_mean - self.x0
        self.r_w = self.whiten(self.resid)
        self.j_raw, self.j_names = self._sensitivities()
        norms = np.linalg.norm(self.whiten_cols(self.j_raw), axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        self.j = self.j_raw / norms
        self.j_w = self.whiten_cols(self.j)

    def gram(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``u.T @ v``, computed once per pair of arrays."""
        key = (id(u), id(v))
        if key not in self._gram:
            self._gram[key] = (u, v, _at_b(u, v))  # the arrays are kept: their ids stay theirs
        return self._gram[key][2]

    def loo_targets(self) -> np.ndarray:
        """``(n, R)``: the whitened residual of the mean of all trials but each one."""
        if self._targets is None:
            trials, r = self.dataset.position_m, self.r_trials
            self._targets = np.stack([self.whiten((trials.sum(axis=0) - trials[i]) / (r - 1.0)
                                                  - self.x0) for i in range(r)], axis=1)
        return self._targets

    def whiten(self, v: np.ndarray) -> np.ndarray:
        nz = self.noise
        return self.lik.whiten(v, nz.sigma, nz.rho, nz.white)

    def whiten_cols(self, cols: np.ndarray) -> np.ndarray:
        return np.stack([self.whiten(c) for c in cols.T], axis=1) if cols.shape[1] else cols

    def _sensitivities(self) -> tuple[np.ndarray, list]:
        model = self.model
        point = dict(model.defaults)
        point.update({k: v for k, v in self.values.items() if k in point})
        base = model.theta(point)[0]
        rows, steps = [base], []
        names = list(model.free_names)
        for name in names:
            j = model.index(name)
            h = 1e-6 * max(abs(base[j]), abs(model.parameter(name).default), 1e-12)
            up = base.copy()
            up[j] += h
            rows.append(up)
            steps.append(h)
        x = self.lik.simulate(np.array(rows))
        cols = np.stack([(x[k + 1] - x[0]) / steps[k] for k in range(len(names))], axis=1)
        return cols, names

    def responses(self, forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unwhitened and whitened output responses ``(n, k)`` to force columns ``(n, k)``."""
        g = force_response(self.plant, forces.T).T
        return g, self.whiten_cols(g)

    def states(self, memory_tau_s: float) -> dict:
        s = self.sim
        v = s.velocity_m_s[0]
        return {"position": s.true_position_m[0], "velocity": v, "pressure": s.pressure_pa[0],
                "hysteresis": s.hysteresis_n[0], "direction": np.sign(v),
                "memory": _low_pass(v, memory_tau_s, self.dataset.dt_s)}

    def blocks(self, memory_tau_s: float) -> list[_Block]:
        out = []
        for name, series in self.states(memory_tau_s).items():
            if name == "direction":
                basis, pen, knots, grid = series[:, None].astype(float), np.eye(1), None, (-1, 1)
            else:
                lo, hi = float(np.min(series)), float(np.max(series))
                if not hi > lo:
                    continue  # a state that never changes carries no information
                basis, knots = _bspline_design(series, _N_BASIS[name], lo, hi)
                pen, grid = _second_difference(basis.shape[1]), (lo, hi)
            g, gw = self.responses(basis)
            scale = float(np.sqrt(np.mean(np.sum(gw**2, axis=0))))
            scale = scale if scale > 0 else 1.0
            out.append(_Block(name, basis, pen, gw / scale, g / scale, scale, knots, grid))
        return out


@dataclass
class _Fit:
    """A penalised fit: coefficients of J and of each block, the evidence, the residual."""

    blocks: list
    log_lambda: np.ndarray
    coef: np.ndarray
    cov: np.ndarray
    log_evidence: float
    energy: float


def _design(problem: _Problem, blocks: list) -> tuple[np.ndarray, list]:
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
    c = _cholesky(q)
    if not np.all(np.isfinite(np.diag(c))):
        return -np.inf
    u = _forward(c, atb[:, None])[:, 0]
    prior = sum(s * ll * math.log(10.0) + ld
                for s, ll, ld in zip(sizes[1:], log_lambda, logdets, strict=True))
    return float(-0.5 * (btb - u @ u) - np.sum(np.log(np.diag(c))) + 0.5 * prior)


def _fit_blocks(problem: _Problem, blocks: list, log_lambda=None) -> _Fit:
    """Penalised GLS; each block's penalty weight by the evidence unless given."""
    a, sizes = _design(problem, blocks)
    ata, atb, btb = _at_b(a, a), _at_b(a, problem.r_w), float(problem.r_w @ problem.r_w)
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
    cov = _spd_solve(q, np.eye(q.shape[0]))
    coef = cov @ atb
    res = problem.r_w - _a_b(a, coef)
    return _Fit(list(blocks), ll, coef, cov, best, float(res @ res))


def _correction(problem: _Problem, blocks: list, coef: np.ndarray) -> np.ndarray:
    """The model output's change, unwhitened: J dtheta + sum of block responses."""
    cols = [problem.j] + [b.response for b in blocks]
    return _a_b(np.concatenate(cols, axis=1), coef)


def _loo(problem: _Problem, blocks: list, log_lambda, extra=None) -> np.ndarray:
    """Leave-one-trial-out log density of each trial with the given terms refitted.

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
    targets = problem.loo_targets()
    gram = np.block([[problem.gram(u, v)[np.ix_(_ix(su, u), _ix(sv, v))]
                      for v, sv in zip(parts, sel, strict=True)]
                     for u, su in zip(parts, sel, strict=True)])
    rhs = np.concatenate([problem.gram(u, targets)[_ix(su, u)]
                          for u, su in zip(parts, sel, strict=True)])
    c2 = (r - 1.0) / r  # the mean of r - 1 trials: its whitening scales by sqrt((r-1)/r)
    coef = _spd_solve(c2 * gram + prec, c2 * rhs)  # (k, r)
    preds = problem.x0[None, :] + _a_b(np.concatenate(raws, axis=1), coef).T
    nz = problem.noise
    return np.diag(lik.pointwise(preds, nz.sigma, nz.rho, nz.white)).copy()


def _ix(sel, arr: np.ndarray) -> np.ndarray:
    return np.arange(arr.shape[1])[sel]


def _elpd_diff(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    d = a - b
    return float(d.sum()), float(math.sqrt(d.size * np.var(d)))


# ---------------------------------------------------------------------------------
# the dictionary of physical terms


@dataclass(frozen=True)
class Term:
    """One named physical term of the closed-form dictionary.

    Parameters
    ----------
    name : str
        The term as written, e.g. ``"v|v|"``.
    unit : str
        Unit of its coefficient (N per unit of the term).
    words : str
        What a force of this form is, physically.
    state : str
        The state it mainly depends on (one of :data:`STATES`).
    force : str or None
        Numba-compatible expression in ``x``, ``v``, ``p``, and ``z`` (the
        hysteretic force) or ``s`` (the memory state) where the term needs them;
        None if it cannot be written as an effect.
    dx, dv : str
        Its derivatives in ``x`` and ``v``.
    dz, ds : str
        Its derivatives in ``z`` and in the memory state.
    slug : str
        Identifier fragment for parameter names.
    period_m : float or None
        For a term periodic in position, its period: ``{L}`` in the expressions,
        written as a parameter of the effect that the refit adjusts.
    breakpoint_m : float or None
        For a spring acting below a position, that position: ``{B}`` in the
        expressions, a parameter of the effect like the period.
    memory_tau_s : float or None
        For the memory term, the time constant of its low-passed velocity ``s``.
    """

    name: str
    unit: str
    words: str
    state: str
    force: str | None
    dx: str = "0.0"
    dv: str = "0.0"
    slug: str = ""
    period_m: float | None = None
    breakpoint_m: float | None = None
    dz: str = "0.0"
    ds: str = "0.0"
    memory_tau_s: float | None = None

    @property
    def writable(self) -> bool:
        """Whether a force-stage effect can express it."""
        return self.force is not None

    @property
    def reads_z(self) -> bool:
        """Whether its effect needs the hysteretic force ``z``."""
        return self.state == "hysteresis"


def _f(value: float) -> str:
    return repr(float(f"{value:.6g}"))


def _dictionary(st: dict, memory_tau_s: float, period_m: float | None, hinges: tuple) -> list:
    """The named terms and their values along the trajectory."""
    x, v, p, z = st["position"], st["velocity"], st["pressure"], st["hysteresis"]
    mm = 1e3
    terms = [
        (Term("1", "N", "a constant force", "position", "1.0", slug="const"), np.ones_like(x)),
        (Term("x^2", "N/m^2", "a quadratic spring", "position", "x * x", "2.0 * x", slug="x2"),
         x**2),
        (Term("x^3", "N/m^3", "a cubic (hardening) spring", "position", "x * x * x",
              "3.0 * x * x", slug="x3"), x**3),
        (Term("v|v|", "N s^2/m^2", "a quadratic drag", "velocity",
              "v * abs(v)", dv="2.0 * abs(v)", slug="vabsv"), v * np.abs(v)),
        (Term("v^3", "N s^3/m^3", "a cubic damping", "velocity", "v * v * v",
              dv="3.0 * v * v", slug="v3"), v**3),
        (Term("|v|", "N s/m", "a force growing with speed in either direction", "velocity",
              "abs(v)", dv="(1.0 if v >= 0.0 else -1.0)", slug="absv"), np.abs(v)),
        (Term("p x", "N/(m Pa)", "a stiffness growing with pressure", "pressure", "p * x",
              "p", slug="px"), p * x),
        (Term("p v", "N s/(m Pa)", "a damping growing with pressure", "pressure", "p * v",
              dv="p", slug="pv"), p * v),
        (Term("p", "N/Pa", "a force proportional to pressure (an area error)", "pressure",
              "p", slug="p"), p),
        (Term("x [v>0]", "N/m", "a stiffness acting only while extending", "direction",
              "(x if v > 0.0 else 0.0)", "(1.0 if v > 0.0 else 0.0)", slug="xext"),
         np.where(v > 0, x, 0.0)),
        (Term("z|z|", "1/N", "a hysteretic force growing as z|z| (a Bouc-Wen exponent above "
              "1)", "hysteresis", "z * abs(z)", dz="2.0 * abs(z)", slug="zabsz"),
         z * np.abs(z)),
        (Term(f"v_lp(tau={memory_tau_s:g} s)", "N s/m",
              f"a force remembering the velocity over {memory_tau_s:g} s (creep, "
              "viscoelastic memory)", "memory", "s", ds="1.0", slug="vlp",
              memory_tau_s=float(memory_tau_s)), st["memory"]),
    ]
    z_big = float(np.max(np.abs(z))) if z.size else 0.0
    if z.min() < -0.1 * z_big and z.max() > 0.1 * z_big:
        # where z keeps one sign, |z| is +-z, and a force c z is the base model itself
        # with alpha, beta and gamma rescaled (z' = (1 + c) z obeys Bouc-Wen's law with
        # (1 + c) alpha, beta / (1 + c), gamma / (1 + c)): not identifiable, so not offered
        terms.append((Term("|z|", "1", "a force in |z| (hysteresis acting one way)",
                           "hysteresis", "abs(z)", dz="(1.0 if z >= 0.0 else -1.0)",
                           slug="absz"), np.abs(z)))
    for v0 in (5e-4, 5e-3, 5e-2):
        s = _f(v0)
        terms.append((Term(f"tanh(v/{v0 * mm:g} mm/s)", "N",
                           f"a friction force, smoothed over {v0 * mm:g} mm/s",
                           "velocity", f"math.tanh(v / {s})",
                           dv=f"(1.0 - math.tanh(v / {s}) ** 2) / {s}",
                           slug=f"tanh{v0 * mm:g}".replace(".", "p")), np.tanh(v / v0)))
    below, above = hinges
    for k, b in enumerate(below):
        terms.append((Term(f"(x - {b * mm:.3g} mm) [x<{b * mm:.3g} mm]", "N/m",
                           f"a spring acting only below x = {b * mm:.3g} mm (in compression)",
                           "position", "((x - {B}) if x < {B} else 0.0)",
                           "(1.0 if x < {B} else 0.0)", slug=f"xlo{k}", breakpoint_m=b),
                      np.where(x < b, x - b, 0.0)))
    for k, b in enumerate(above):
        s = _f(b)
        terms.append((Term(f"(x - {b * mm:.3g} mm) [x>{b * mm:.3g} mm]", "N/m",
                           f"a spring engaging only above x = {b * mm:.3g} mm (an end stop)",
                           "position", f"((x - {s}) if x > {s} else 0.0)",
                           f"(1.0 if x > {s} else 0.0)", slug=f"xhi{k}"),
                      np.where(x > b, x - b, 0.0)))
    if period_m is not None:
        k = "6.283185307179586"
        words = (f"a force periodic in position with a period of {period_m * mm:.3g} mm "
                 "(detents of a rail, a ratchet)")
        terms.append((Term(f"sin(2 pi x / {period_m * mm:.3g} mm)", "N", words, "position",
                           f"math.sin({k} * x / {{L}})",
                           f"{k} / {{L}} * math.cos({k} * x / {{L}})", slug="sin",
                           period_m=period_m), np.sin(2 * math.pi * x / period_m)))
        terms.append((Term(f"cos(2 pi x / {period_m * mm:.3g} mm)", "N", words, "position",
                           f"math.cos({k} * x / {{L}})",
                           f"-{k} / {{L}} * math.sin({k} * x / {{L}})", slug="cos",
                           period_m=period_m), np.cos(2 * math.pi * x / period_m)))
    return terms


def _best_of(problem: _Problem, families: list) -> int:
    """Index of the family of force columns (each ``(n, k)``) that removes most residual."""
    forces = np.concatenate(families, axis=1)
    _, gw = problem.responses(forces)
    q = _orthonormal(problem.j_w)
    r0 = problem.r_w - _a_b(q, _at_b(q, problem.r_w))
    gains, k = [], 0
    for fam in families:
        g = gw[:, k:k + fam.shape[1]]
        k += fam.shape[1]
        g = g - _a_b(q, _at_b(q, g))
        coef = _spd_solve(_at_b(g, g) + 1e-12 * np.eye(g.shape[1]), _at_b(g, r0))
        gains.append(float(r0 @ r0 - np.sum((r0 - _a_b(g, coef)) ** 2)))
    return int(np.argmax(gains))


def _best_period(problem: _Problem, x: np.ndarray) -> float | None:
    """The period of a force periodic in position that best explains the residual."""
    span = float(np.ptp(x))
    if not span > 0:
        return None
    def fams(periods):
        return [np.stack([np.sin(2 * np.pi * x / L), np.cos(2 * np.pi * x / L)], axis=1)
                for L in periods]

    coarse = np.geomspace(span / 60.0, span / 2.0, 48)
    best = coarse[_best_of(problem, fams(coarse))]
    # then finely: over the span a period off by 1% drifts by a tenth of a period
    fine = best * np.geomspace(0.93, 1.075, 41)
    return float(fine[_best_of(problem, fams(fine))])


def _best_hinges(problem: _Problem, x: np.ndarray) -> tuple:
    """Where a spring acting only below (and one acting only above) a position best fits."""
    below = np.quantile(x, np.linspace(0.02, 0.6, 30))
    above = np.quantile(x, np.linspace(0.4, 0.98, 30))
    b = below[_best_of(problem, [np.where(x < c, x - c, 0.0)[:, None] for c in below])]
    a = above[_best_of(problem, [np.where(x > c, x - c, 0.0)[:, None] for c in above])]
    return (float(b),), (float(a),)


# ---------------------------------------------------------------------------------
# results


@dataclass(frozen=True)
class StateEvidence:
    """The evidence that the missing force depends on one state.

    Parameters
    ----------
    state : str
        One of :data:`STATES`.
    unit : str
        Its unit.
    elpd_loss : float
        Leave-one-trial-out ELPD lost when the state's terms are dropped from the
        flexible force (positive: the state is needed).
    se : float
        Standard error of ``elpd_loss`` from the per-trial differences.
    amplitude_n : float
        RMS along the trajectory of the force's partial dependence on the state.
    needed : bool
        ``elpd_loss`` above two standard errors (and above 2).
    """

    state: str
    unit: str
    elpd_loss: float
    se: float
    amplitude_n: float
    needed: bool

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class Proposal:
    """A closed form for the missing force, ready as a user effect.

    Parameters
    ----------
    effect : str
        The proposed effect's registry name.
    expression : str
        The force as a formula, with the estimated coefficients and units.
    description : str
        The force in physical words.
    terms : list of dict
        ``{"term", "unit", "coefficient", "parameter", "words", "writable"}`` per term.
    kind : str
        ``"closed form"`` (a sparse sum of dictionary terms) or ``"tabulated"`` (the
        flexible shape in one state, with one amplitude).
    elpd_diff : float
        Leave-one-trial-out ELPD of the proposal minus the flexible estimate's.
    elpd_diff_se : float
        Its standard error.
    plugin : str or None
        Path of the written ``.py`` file; None when a term cannot be written as a
        force effect today (it needs ``z`` or memory), or nothing was written.
    verified : dict or None
        The nonlinear refit with the written effect: ``{"rms_m", "ratio", "energy",
        "ljung_box_p", "adequate", "values"}``.
    """

    effect: str
    expression: str
    description: str
    terms: list
    kind: str
    elpd_diff: float
    elpd_diff_se: float
    plugin: str | None
    verified: dict | None

    def to_dict(self) -> dict:
        """JSON-ready summary (``effect``, ``expression``, ``plugin`` and the details)."""
        return {"effect": self.effect, "expression": self.expression,
                "plugin": self.plugin, "description": self.description,
                "kind": self.kind, "terms": list(self.terms), "elpd_diff": self.elpd_diff,
                "elpd_diff_se": self.elpd_diff_se, "verified": self.verified}


@dataclass(frozen=True)
class Discrepancy:
    """The missing force estimated from the data, its states and a proposed closed form.

    Parameters
    ----------
    states : list of StateEvidence
        Every state, most evidence first.
    explained : float
        Share of the whitened residual's excess energy (above the noise) that the
        flexible force, with the parameters readjusted, removes (linearised).
    ratio_after : float
        RMS error over the floor with the flexible force (linearised).
    elpd_gain : float
        Leave-one-trial-out ELPD of the flexible force minus that of the model with
        its parameters readjusted alone.
    elpd_gain_se : float
        Its standard error.
    memory_tau_s : float
        Time constant of the memory state (low-passed velocity), by the evidence.
    partial_dependence : dict
        State to ``{"grid", "force_n", "sd_n", "unit"}``: the flexible force's
        shape against that state (centred along the trajectory) and its posterior sd.
    proposal : Proposal or None
        The closed form (or tabulated shape), None when none could be formed.
    near_floor : bool
        Whether the flexible force brings the model near the floor (ratio within
        1.5x).
    other_cause : str or None
        When the flexible force cannot: what is left and which non-force cause the
        residual's signature suggests.
    text : str
        The conclusion in words.
    """

    states: list
    explained: float
    ratio_after: float
    elpd_gain: float
    elpd_gain_se: float
    memory_tau_s: float
    partial_dependence: dict
    proposal: Proposal | None
    near_floor: bool
    other_cause: str | None
    text: str
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready summary (the ``discrepancy`` key of ``pmabayes diagnose --json``)."""
        return {"states": [s.to_dict() for s in self.states], "explained": self.explained,
                "ratio_after": self.ratio_after, "elpd_gain": self.elpd_gain,
                "elpd_gain_se": self.elpd_gain_se, "memory_tau_s": self.memory_tau_s,
                "near_floor": self.near_floor, "other_cause": self.other_cause,
                "proposal": None if self.proposal is None else self.proposal.to_dict(),
                "text": self.text}


# ---------------------------------------------------------------------------------
# the estimate


def estimate_discrepancy(
    likelihood: Likelihood,
    noise,
    values: dict,
    simulation: Simulation,
    *,
    plugin_dir: str | Path | None = None,
    verify: bool = True,
    command: str | None = None,
    effects=(),
) -> Discrepancy:
    """Estimate the missing force from the data and propose a closed form for it.

    Parameters
    ----------
    likelihood : Likelihood
        Data and the diagnosed model.
    noise : object
        Identified noise (``sigma``, ``rho``, ``white``).
    values : dict
        The model's MAP.
    simulation : Simulation
        The model at its MAP, with its states.
    plugin_dir : str or Path, optional
        Where to write the proposal's ``.py`` file (the current folder by default).
        An existing file of the same name is never overwritten: a numbered name is
        chosen instead.
    verify : bool
        Refit the model with the written effect (nonlinear, through the simulator)
        and report what it achieves.
    command : str, optional
        The data's path for the suggested command line.
    effects : iterable of str
        The diagnosed model's effects, for the suggested command line.

    Returns
    -------
    Discrepancy
    """
    problem = _Problem(likelihood, noise, values, simulation)
    n = problem.n
    e0 = float(problem.r_w @ problem.r_w)
    # the memory state's time constant, by the evidence
    fits = {}
    for tau in MEMORY_TAUS_S:
        fits[tau] = _fit_blocks(problem, problem.blocks(tau))
    tau = max(fits, key=lambda t: fits[t].log_evidence)
    full = fits[tau]
    blocks = full.blocks
    only_j = _fit_blocks(problem, [], [])
    loo_full = _loo(problem, blocks, full.log_lambda)
    loo_none = _loo(problem, [], [])
    gain, gain_se = _elpd_diff(loo_full, loo_none)
    excess = max(e0 - n, 1e-12)
    explained = float(np.clip((only_j.energy - full.energy) / excess, 0.0, 1.0)) \
        if e0 > n else 0.0
    corr = _correction(problem, blocks, full.coef)
    ratio_after = band_errors(problem.dataset, problem.x0 + corr)[-1].ratio
    # states: ELPD lost by dropping each, and the partial dependence
    states, pdep = [], {}
    units = {s: u for s, u, _ in STATES}
    k0 = problem.j.shape[1]
    offsets = np.cumsum([k0] + [b.white.shape[1] for b in blocks])
    for i, b in enumerate(blocks):
        rest = [c for c in blocks if c is not b]
        ll = np.delete(full.log_lambda, i)
        loss, se = _elpd_diff(loo_full, _loo(problem, rest, ll))
        sl = slice(offsets[i], offsets[i] + b.white.shape[1])
        w = full.coef[sl] / b.scale
        along = _a_b(b.basis, w)
        amp = float(np.std(along))
        states.append(StateEvidence(b.state, units[b.state], loss, se, amp,
                                    bool(loss > max(2.0 * se, 2.0))))
        pdep[b.state] = _partial(b, w, full.cov[sl, sl] / b.scale**2, float(np.mean(along)))
    states.sort(key=lambda s: -s.elpd_loss)
    near = bool(ratio_after <= 1.5)
    st = problem.states(tau)
    proposal = None
    if gain > max(2.0 * gain_se, 2.0):
        proposal = _propose(problem, st, tau, blocks, full, loo_full, gain, states,
                            plugin_dir, verify, command)
    other = None if near and explained >= 0.5 else _other_cause(
        likelihood, noise, simulation, explained, ratio_after)
    text = _text(states, explained, ratio_after, gain, gain_se, proposal, other, command,
                 tuple(effects))
    return Discrepancy(states=states, explained=explained, ratio_after=float(ratio_after),
                       elpd_gain=gain, elpd_gain_se=gain_se, memory_tau_s=float(tau),
                       partial_dependence=pdep, proposal=proposal, near_floor=near,
                       other_cause=other, text=text)


def _partial(b: _Block, w: np.ndarray, cov: np.ndarray, mean: float) -> dict:
    lo, hi = b.grid
    if b.state == "direction":
        grid = np.array([-1.0, 1.0])
        basis = grid[:, None]
    else:
        grid = np.linspace(lo, hi, 120)
        basis, _ = _bspline_design(grid, b.basis.shape[1], lo, hi)
    f = basis @ w - mean
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", basis, cov, basis), 0.0))
    return {"grid": grid, "force_n": f, "sd_n": sd,
            "unit": {s: u for s, u, _ in STATES}[b.state]}


def _propose(problem, st, tau, blocks, full, loo_full, gain, states, plugin_dir, verify,
             command):
    """STLSQ over the dictionary, the threshold by LOO ELPD; else the tabulated shape."""
    period = _best_period(problem, st["position"])
    terms = _dictionary(st, tau, period, _best_hinges(problem, st["position"]))
    forces = np.stack([t[1] for t in terms], axis=1)
    raw, white = problem.responses(forces)
    scale = np.linalg.norm(white, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    raw, white = raw / scale, white / scale
    a = np.concatenate([problem.j_w, white], axis=1)
    k0 = problem.j_w.shape[1]
    supports = _stlsq_path(a, problem.r_w, k0) | _forward_path(problem.j_w, white, problem.r_w)
    scored = []
    for support in sorted(supports, key=lambda t: (len(t), t)):
        idx = list(support)
        loo = _loo(problem, [], [], extra=(white, raw, idx))
        d, se = _elpd_diff(loo, loo_full)
        scored.append((d, se, support))
    best = None
    if scored:
        top_d = max(c[0] for c in scored)
        # the sparsest support within two standard errors (or 2) of the best
        best = min((c for c in scored if c[0] >= top_d - max(2.0 * c[1], 2.0)),
                   key=lambda c: (len(c[2]), -c[0]))
    top = states[0].state if states else None
    closed = None
    if best is not None:
        d, se, support = best
        idx = list(support)
        sub = np.concatenate([problem.j_w, white[:, idx]], axis=1)
        w = stlsq(sub, problem.r_w, 0.0, keep=range(sub.shape[1]))
        chosen = [(terms[j][0], float(w[k0 + i] / scale[j])) for i, j in enumerate(idx)]
        # near the flexible estimate: within its noise, or a small share of its gain
        matches = d > -max(2.0 * se, 4.0, 0.02 * gain)
        closed = (chosen, d, se, matches)
    series = {t.slug: v for t, v in terms}
    folder = Path(plugin_dir) if plugin_dir is not None else Path.cwd()
    existing = {str(f) for f in folder.glob("*.py")} if folder.is_dir() else set()
    if closed is not None and closed[3]:
        chosen, d, se, _ = closed
        prop = _write_proposal(problem, chosen, "closed form", d, se, plugin_dir, verify,
                               command, series=series)
        plain = [c for c in scored if all(terms[j][0].state in WRITABLE for j in c[2])]
        v = prop.verified
        if (v is None or (v["adequate"] and v["ratio"] <= 1.5) or not plain
                or all(t.state in WRITABLE for t, _ in chosen)):
            return prop
        # terms in z or memory trade against the base model's own parameters in the
        # nonlinear refit; when that refit fails, the best support in (x, v, p) alone
        # is refitted too, and the better of the two is proposed
        d2, se2, support2 = max(plain, key=lambda c: c[0])
        idx = list(support2)
        sub = np.concatenate([problem.j_w, white[:, idx]], axis=1)
        w = stlsq(sub, problem.r_w, 0.0, keep=range(sub.shape[1]))
        chosen2 = [(terms[j][0], float(w[k0 + i] / scale[j])) for i, j in enumerate(idx)]
        prop2 = _write_proposal(problem, chosen2, "closed form", d2, se2, plugin_dir, verify,
                                command, series=series)
        v2 = prop2.verified
        better = v2 is not None and (v2["adequate"], -v2["ratio"]) > (v["adequate"],
                                                                       -v["ratio"])
        keep, drop = (prop2, prop) if better else (prop, prop2)
        if drop.plugin is not None and drop.plugin not in existing:
            Path(drop.plugin).unlink(missing_ok=True)  # written by this run, not kept
        return keep
    if closed is not None and verify and all(t.writable for t, _ in closed[0]):
        # the linearisation may be what keeps it from the flexible estimate (a steep
        # force, a period slightly off): the nonlinear refit decides
        chosen, d, se, _ = closed
        prop = _write_proposal(problem, chosen, "closed form", d, se, plugin_dir, verify,
                               command, series=series)
        v = prop.verified
        if v is not None and v["adequate"] and v["ratio"] <= 1.5:
            return prop
        if prop.plugin is not None and prop.plugin not in existing:
            Path(prop.plugin).unlink(missing_ok=True)  # written by this run, not kept
    # no closed form near the flexible estimate: the flexible shape itself, tabulated
    if top in WRITABLE:
        b = next(b for b in blocks if b.state == top)
        i = blocks.index(b)
        k = problem.j.shape[1] + sum(c.white.shape[1] for c in blocks[:i])
        w = full.coef[k:k + b.white.shape[1]] / b.scale
        term, shape_w = _tabulated_term(b, w)
        col = term[1][:, None]
        r, wh = problem.responses(col)
        loo = _loo(problem, [], [], extra=(wh, r, [0]))
        d, se = _elpd_diff(loo, loo_full)
        return _write_proposal(problem, [(term[0], 1.0)], "tabulated", d, se, plugin_dir,
                               verify, command, tables=shape_w)
    if closed is not None:
        chosen, d, se, _ = closed
        return _write_proposal(problem, chosen, "closed form", d, se, plugin_dir, verify,
                               command, series={t.slug: v for t, v in terms})
    return None


def _stlsq_path(a: np.ndarray, b: np.ndarray, k0: int, max_terms: int = 4) -> set:
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


def _forward_path(j: np.ndarray, cols: np.ndarray, b: np.ndarray, max_terms: int = 4) -> set:
    """Supports of greedy forward selection (each step the term removing most energy)."""
    q = _orthonormal(j)
    r = b - _a_b(q, _at_b(q, b))
    c = cols - _a_b(q, _at_b(q, cols))
    cc, cr = _at_b(c, c), _at_b(c, r)
    chosen, out = [], set()
    for _ in range(max_terms):
        best, gain = None, -1.0
        for k in range(c.shape[1]):
            if k in chosen:
                continue
            ix = [*chosen, k]
            g = cr[ix]
            try:
                coef = _spd_solve(cc[np.ix_(ix, ix)] + 1e-10 * np.eye(len(ix)), g)
            except np.linalg.LinAlgError:
                continue
            if g @ coef > gain:
                best, gain = k, float(g @ coef)
        if best is None:
            break
        chosen.append(best)
        out.add(tuple(sorted(chosen)))
    return out


def _tabulated_term(b: _Block, w: np.ndarray):
    """The flexible shape in one state as a piecewise cubic with fixed coefficients."""
    spline = BSpline(b.knots, w, 3, extrapolate=False)
    pp = PPoly.from_spline(spline)
    keep = np.flatnonzero(np.diff(pp.x) > 0)
    brk = np.concatenate([pp.x[keep], [pp.x[keep[-1] + 1]]])
    coefs = pp.c[:, keep]
    sym = {"position": "x", "velocity": "v", "pressure": "p"}[b.state]
    series = _a_b(b.basis, w)
    mean = float(np.mean(series))
    coefs = coefs.copy()
    coefs[-1] -= mean  # centred: a constant would shift the rest position only
    values = series - mean
    t = Term(f"S_{sym}({sym})", "1", f"the estimated force shape in {b.state}, tabulated",
             b.state, "shape", "0.0", "0.0", slug=f"shape_{sym}")
    if sym == "x":
        t = Term(t.name, t.unit, t.words, t.state, t.force, "slope", "0.0", t.slug)
    elif sym == "v":
        t = Term(t.name, t.unit, t.words, t.state, t.force, "0.0", "slope", t.slug)
    return (t, values), (brk, coefs)


def _effect_name(chosen: list) -> str:
    slugs = [t.slug for t, _ in chosen]
    return "proposed_" + "_".join(slugs)[:40]  # its parameters are c_<slug>: unique names


def _plugin_source(name: str, chosen: list, description: str, tables=None) -> str:
    """The text of a ready user effect for ``--plugin``."""
    lines = [f'"""A proposed effect: {description}',
             "",
             "Written by pmabayes' discrepancy step from the data's residual (an estimate,",
             "not a law: check it with `pmabayes diagnose DATA --effects "
             f"{name}` after --plugin).",
             '"""', "", "import math", "", "import numpy as np", "",
             "import pmabayes as pb", ""]
    if tables is not None:
        brk, coefs = tables
        lines += [f"_BREAKS = np.array({[float(f'{b:.10g}') for b in brk]!r})",
                  "_COEFS = np.array(" + repr([[float(f"{c:.10g}") for c in row]
                                               for row in coefs]) + ")", "", "",
                  ]
    reads_z = any(t.reads_z for t, _ in chosen)
    tau = next((t.memory_tau_s for t, _ in chosen if t.memory_tau_s is not None), None)
    extended = reads_z or tau is not None  # the signature of effects that read z or s
    if tau is not None:
        # the low-passed velocity s' = (v - s) / tau, exact over a step of constant v
        lines += ["", f"_TAU_S = {float(tau)!r}", "", "",
                  "def _advance(q, s, x0, x1, h):",
                  '    """The memory state over a step: exact for a constant velocity."""',
                  "    e = math.exp(-h / _TAU_S)",
                  "    return s * e + (1.0 - e) * (x1 - x0) / h, (1.0 - e) / h", ""]
    if extended:
        lines += ["", "def _physics(q, x, v, p, z, s):",
                  '    """Force opposing extension, and its derivatives in x, v, z and s."""',
                  "    f = 0.0", "    fx = 0.0", "    fv = 0.0", "    fz = 0.0", "    fs = 0.0"]
    else:
        lines += ["", "def _physics(q, x, v, p):",
                  '    """Force opposing extension, and its derivatives in x and v."""',
                  "    f = 0.0", "    fx = 0.0", "    fv = 0.0"]
    if tables is not None:
        # the table is evaluated inline: a compiled helper would be a second function the
        # simulator's cached kernel could not find again in a later process
        sym = {"position": "x", "velocity": "v", "pressure": "p"}[chosen[0][0].state]
        lines += [f"    s = {sym}",
                  "    if s <= _BREAKS[0]:",
                  "        k = 0", "        h = 0.0", "        inside = 0.0",
                  "    elif s >= _BREAKS[-1]:",
                  "        k = _BREAKS.size - 2", "        h = _BREAKS[-1] - _BREAKS[k]",
                  "        inside = 0.0",
                  "    else:",
                  "        k = np.searchsorted(_BREAKS, s) - 1", "        h = s - _BREAKS[k]",
                  "        inside = 1.0",
                  "    shape = ((_COEFS[0, k] * h + _COEFS[1, k]) * h + _COEFS[2, k]) * h "
                  "+ _COEFS[3, k]",
                  "    slope = inside * ((3.0 * _COEFS[0, k] * h + 2.0 * _COEFS[1, k]) * h "
                  "+ _COEFS[2, k])"]
    period = next((t.period_m for t, _ in chosen if t.period_m is not None), None)
    brk = next((t.breakpoint_m for t, _ in chosen if t.breakpoint_m is not None), None)
    per = f"q[{len(chosen)}]"  # the period, after the coefficients, then the breakpoint
    bq = f"q[{len(chosen) + (period is not None)}]"

    def fill(expr: str) -> str:
        return expr.replace("{L}", per).replace("{B}", bq)

    for k, (t, _) in enumerate(chosen):
        lines.append(f"    f += q[{k}] * ({fill(t.force)})")
        if t.dx != "0.0":
            lines.append(f"    fx += q[{k}] * ({fill(t.dx)})")
        if t.dv != "0.0":
            lines.append(f"    fv += q[{k}] * ({fill(t.dv)})")
        if t.dz != "0.0":
            lines.append(f"    fz += q[{k}] * ({t.dz})")
        if t.ds != "0.0":
            lines.append(f"    fs += q[{k}] * ({t.ds})")
    lines += ["    return f, fx, fv" + (", fz, fs" if extended else ""), "", "",
              "class ProposedEffect(pb.Effect):", f'    """{description}"""', "",
              f"    name = {name!r}", '    stage = "force"']
    if reads_z:
        lines.append("    reads_z = True")
    if tau is not None:
        lines += ['    state = "v_lp_m_s"', "    advance = staticmethod(_advance)"]
    lines.append("    parameters = (")
    for t, coef in chosen:
        pname = f"c_{t.slug}"
        sd = max(2.0 * abs(coef), 1e-12)
        lo, hi = coef - 50.0 * sd, coef + 50.0 * sd
        lo, hi = min(lo, 0.0), max(hi, 0.0)
        lines.append(f"        pb.Parameter({pname!r}, {t.unit!r}, {coef!r}, "
                     f"pb.Normal({coef!r}, {sd!r}), bounds=({lo!r}, {hi!r}), null=0.0,")
        meaning = f"coefficient of {t.name}: {t.words}"
        lines.append(f"                     description={meaning!r}),")
    if period is not None:
        lines.append(f"        pb.Parameter('L_period', 'm', {period!r}, pb.Normal({period!r}, "
                     f"{0.03 * period!r}), bounds=({0.8 * period!r}, {1.25 * period!r}), "
                     f"null={period!r},")
        lines.append("                     description='period in position of the force'),")
    if brk is not None:
        lines.append(f"        pb.Parameter('x_break', 'm', {brk!r}, pb.Normal({brk!r}, 0.01), "
                     f"bounds=({brk - 0.05!r}, {brk + 0.05!r}), null={brk!r},")
        lines.append("                     description='position below which the spring "
                     "acts'),")
    lines += ["    )", f"    description = {description!r}", "    physics = staticmethod(_physics)",
              ""]
    return "\n".join(lines) + "\n"


_REGISTER = ("\n# pmabayes' own check of this proposal imports the file without registering it\n"
             "if __name__ != 'pmabayes_discrepancy_check':\n"
             "    pb.register_effect(ProposedEffect)\n")


#: slugs of the dictionary's terms odd in velocity (a force along -v when positive)
_ODD_IN_V = ("vabsv", "v3", "tanh")


def _describe(chosen: list, kind: str) -> tuple[str, str]:
    if kind == "tabulated":
        t = chosen[0][0]
        return (f"{t.name}", f"a force with the estimated shape against {t.state}, "
                "tabulated with one amplitude (no closed form in the dictionary matches it)")
    parts, words = [], []
    for t, c in chosen:
        parts.append(f"{c:+.4g} {t.unit} * {t.name}")
        if t.state == "velocity" and t.slug.startswith(_ODD_IN_V):
            # odd in v: the sign says whether it opposes or aids the motion
            sense = "opposing motion" if c > 0 else "aiding motion"
        else:
            sense = "opposing extension" if c > 0 else "toward extension"
        words.append(f"a force of about {abs(c):.3g} {t.unit} times {t.name}, {sense}: "
                     f"{t.words}")
    return " ".join(parts).lstrip("+"), "; ".join(words)


def _write_plugin(chosen: list, kind: str, tables, plugin_dir) -> tuple[Path, bool]:
    """Write the effect's file; never over another file. Its path, and whether it is new."""
    _, description = _describe(chosen, kind)
    name = _effect_name(chosen)
    body = _plugin_source(name, chosen, description, tables) + _REGISTER
    folder = Path(plugin_dir) if plugin_dir is not None else Path.cwd()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.py"
    k = 2
    while path.exists() and path.read_text() != body:
        path = folder / f"{name}_{k}.py"  # never overwrite another file silently
        k += 1
    created = not path.exists()
    path.write_text(body)
    return path, created


def _write_proposal(problem, chosen, kind, d, se, plugin_dir, verify, command, tables=None,
                    series=None):
    """Write the proposal as an effect, refit it, and drop terms the refit finds negligible."""
    taken = set(problem.model.parameter_names) | {f"c_{n}" for n in problem.model.effect_names}
    renamed = []
    for t, c in chosen:  # a model that already holds an earlier proposal keeps its names
        slug, k = t.slug, 2
        while f"c_{slug}" in taken:
            slug, k = f"{t.slug}{k}", k + 1
        taken.add(f"c_{slug}")
        if series is not None:
            series = {**series, slug: series[t.slug]}
        renamed.append((replace(t, slug=slug), c))
    chosen = renamed
    plugin = verified = None
    told = chosen
    if all(t.writable for t, _ in chosen):
        path, created = _write_plugin(chosen, kind, tables, plugin_dir)
        if verify:
            verified = _verify(problem, path, chosen)
            told = [(t, verified["values"][f"c_{t.slug}"]) for t, _ in chosen]
            if kind == "closed form" and series is not None and len(chosen) > 1:
                # a term that only compensated the linearisation shrinks in the refit
                amps = [float(np.std(c * series[t.slug])) for t, c in told]
                keep = [tc for tc, a in zip(told, amps, strict=True) if a >= 0.1 * max(amps)]
                if len(keep) < len(told):
                    if created:
                        path.unlink()  # written by this run, and superseded
                    chosen = keep
                    path, created = _write_plugin(chosen, kind, tables, plugin_dir)
                    verified = _verify(problem, path, chosen)
                    told = [(t, verified["values"][f"c_{t.slug}"]) for t, _ in chosen]
        plugin = str(path)
    if verified is not None and "L_period" in verified["values"]:
        mm = verified["values"]["L_period"] * 1e3  # the refitted period, in the words too
        told = [(replace(t, name=re.sub(r"/ [0-9.e+-]+ mm\)", f"/ {mm:.4g} mm)", t.name),
                         words=re.sub(r"period of [0-9.e+-]+ mm", f"period of {mm:.4g} mm",
                                      t.words)), c) for t, c in told]
    if verified is not None and "x_break" in verified["values"]:
        mm = verified["values"]["x_break"] * 1e3  # the refitted breakpoint, in the words too
        told = [(replace(t, name=re.sub(r"-?[0-9.]+(e[+-]?[0-9]+)? mm", f"{mm:.3g} mm", t.name),
                         words=re.sub(r"-?[0-9.]+(e[+-]?[0-9]+)? mm", f"{mm:.3g} mm", t.words))
                 if t.breakpoint_m is not None else t, c) for t, c in told]
    expression, description = _describe(told, kind)
    terms = [{"term": t.name, "unit": t.unit, "coefficient": c, "parameter": f"c_{t.slug}",
              "words": t.words, "writable": t.writable} for t, c in told]
    return Proposal(effect=_effect_name(chosen), expression=expression,
                    description=description, terms=terms, kind=kind, elpd_diff=float(d),
                    elpd_diff_se=float(se), plugin=plugin, verified=verified)


def _load_unregistered(path: Path):
    spec = importlib.util.spec_from_file_location("pmabayes_discrepancy_check", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules.pop("pmabayes_discrepancy_check", None)
    spec.loader.exec_module(module)
    return module.ProposedEffect


def _verify(problem: _Problem, path: Path, chosen: list, n_iter: int = 12) -> dict:
    """Refit the model with the written effect: Gauss-Newton on the whitened residual."""
    eff = _load_unregistered(path)
    model = problem.model.with_effects(eff)
    lik = Likelihood(model, problem.dataset, substeps=problem.lik.substeps)
    start = {k: v for k, v in problem.values.items() if k in model.parameter_names}
    # the coefficients; a period parameter after them starts at its default
    start.update({p.name: c for p, (_, c) in zip(eff.parameters, chosen, strict=False)})
    values = _gauss_newton(lik, problem.noise, model, start, n_iter)
    sim = simulate_dataset(model, values, problem.dataset, substeps=lik.substeps, states=True)
    sig = residual_signature(lik, problem.noise, sim)
    return {"rms_m": sig.bands[-1].rms_m, "ratio": sig.ratio, "energy": sig.energy,
            "ljung_box_p": sig.ljung_box_p, "adequate": bool(sig.is_adequate()),
            "values": {p.name: values[p.name] for p in eff.parameters}}


def _gauss_newton(lik: Likelihood, noise, model: Model, start: dict, n_iter: int) -> dict:
    """Levenberg-Marquardt on the whitened residual of the trial mean, within the bounds."""
    names = list(model.free_names)
    theta = model.theta(start)[0]
    idx = [model.index(n) for n in names]
    lo = np.array([model.parameter(n).bounds[0] for n in names])
    hi = np.array([model.parameter(n).bounds[1] for n in names])

    def whiten(v):
        return lik.whiten(v, noise.sigma, noise.rho, noise.white)

    def cost(th):
        x = lik.simulate(th[None])[0]
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
        xs = lik.simulate(rows)
        jw = np.stack([whiten((xs[k + 1] - xs[0]) / h[k]) for k in range(len(idx))], axis=1)
        norms = np.linalg.norm(jw, axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        jn = jw / norms
        ata, atb = _at_b(jn, jn), _at_b(jn, r0)
        improved = False
        for _ in range(8):
            # a parameter the output does not see (at a bound, a vanishing term) has a
            # zero column: the identity term keeps the damped system definite
            damped = ata + mu * np.diag(np.diag(ata)) + 1e-9 * np.eye(len(idx))
            try:
                step = _spd_solve(damped, atb) / norms
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


def _other_cause(lik, noise, sim, explained: float, ratio_after: float) -> str:
    """What the flexible force leaves, and which non-force cause the signature suggests."""
    sig = residual_signature(lik, noise, sim)
    corr = sig.correlations
    name, value = max(corr.items(), key=lambda kv: abs(kv[1])) if corr else ("", 0.0)
    text = (f"Even a flexible force in the states leaves the model at {ratio_after:.3g}x the "
            f"floor (it explains {explained:.0%} of the excess residual): the missing piece "
            "may not be a force.")
    timing = abs(sig.ccf_peak) > sig.ccf_bound and sig.ccf_lag_s > 0
    if "position" in name and abs(value) > 0.5:
        text += (f" The residual follows the position (r = {value:+.2f}): an error "
                 "proportional to the position suggests the sensor (its scale or zero).")
    elif timing or "rate" in name or "command" in name:
        text += (f" The whitened residual correlates with the command's rate "
                 f"{sig.ccf_lag_s * 1e3:.0f} ms earlier (correlation {sig.ccf_peak:+.2f}): a "
                 "timing problem (a delay or a clock between command and measurement).")
    else:
        text += (" The residual follows no state or rate clearly: suspect the input (the "
                 "pressure acting differs from the command recorded) or the noise model.")
    return text


def _text(states, explained, ratio_after, gain, gain_se, proposal, other, command,
          effects) -> str:
    needed = [s for s in states if s.needed]
    if not needed and not gain > max(2.0 * gain_se, 2.0):
        return ("A flexible force in the states does not predict left-out trials better "
                f"(ΔELPD {gain:+.1f} ± {gain_se:.1f}): no discrepancy in the force is found.")
    dep = ", ".join(f"{s.state} (ΔELPD {s.elpd_loss:+.1f} ± {s.se:.1f})" for s in needed) or \
        "no single state"
    text = (f"A flexible force estimated from the data removes {explained:.0%} of the excess "
            f"residual (to {ratio_after:.3g}x the floor, linearised; ΔELPD {gain:+.1f} ± "
            f"{gain_se:.1f}). It depends on {dep}.")
    if proposal is not None:
        text += f" Proposed: {proposal.description} ({proposal.expression})."
        if proposal.plugin:
            v = proposal.verified
            if v is not None:
                text += (f" Refitted with it, the model reaches {v['ratio']:.3g}x the floor"
                         f" ({'adequate' if v['adequate'] else 'not adequate'}).")
            data = command or "DATA"
            names = ",".join([*effects, proposal.effect])
            text += (f" To add it: pmabayes --plugin {proposal.plugin} diagnose {data} "
                     f"--effects {names}")
        else:
            text += " It could not be written as an effect."
    if other:
        text += " " + other
    return text
