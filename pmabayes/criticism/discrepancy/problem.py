"""The whitened linear problem around the MAP: the residual, the sensitivities to the
model's parameters, and the flexible force's blocks (cubic B-splines in each state).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline

from pmabayes.criticism.discrepancy.linalg import at_b
from pmabayes.criticism.discrepancy.response import force_response, linearised_plant
from pmabayes.criticism.observed import counted_samples, model_mean, residual
from pmabayes.criticism.scores import _stepped_rows
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.simulator import Simulation

__all__ = ["STATES"]


#: the states the flexible force may depend on: name, unit, symbol
#:
#: :meta hide-value:
STATES = (("position", "m", "x"), ("velocity", "m/s", "v"), ("pressure", "Pa", "p"),
          ("hysteresis", "N", "z"), ("direction", "1", "sgn v"),
          ("memory", "m/s", "v_lp"), ("loop", "1", "h"))


#: spline basis functions per state (position resolves detents of ~4 knot spacings)
_N_BASIS = {"position": 64, "velocity": 16, "pressure": 12, "hysteresis": 12, "memory": 12,
            "loop": 8}


#: time constants scanned for the memory state (low-passed velocity), s
MEMORY_TAUS_S = (0.1, 0.4, 1.6)


#: widths scanned for the loop state (a second hysteresis loop, Dahl's friction model:
#: it saturates over this much travel after each reversal), m
LOOP_WIDTHS_M = (0.5e-3, 2e-3, 8e-3)


#: states a force effect can be written in today (force-stage physics gets x, v, p)
WRITABLE = ("position", "velocity", "pressure")


#: folds of a record without repeats: its cross-validation leaves one out at a time where
#: a record with repeats leaves out one trial. The record is cut into
#: ``N_FOLDS * STRETCHES_PER_FOLD`` contiguous stretches dealt to the folds in turn, so
#: that every fold spans the whole input (a chirp's slow start and fast end alike) and
#: the folds' scores compare
N_FOLDS = 10
STRETCHES_PER_FOLD = 5


def bspline_design(s: np.ndarray, n_basis: int, lo: float, hi: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Cubic B-spline basis over ``[lo, hi]`` (clamped knots) at ``s``: the design
    ``(len(s), n_basis)`` and the knots."""
    inner = np.linspace(lo, hi, n_basis - 2)
    t = np.concatenate([[lo] * 3, inner, [hi] * 3])
    return BSpline.design_matrix(np.clip(s, lo, hi), t, 3).toarray(), t


def low_pass(v: np.ndarray, tau_s: float, dt_s: float) -> np.ndarray:
    """The memory state: ``v`` low-passed with time constant ``tau_s`` (first order)."""
    a = math.exp(-dt_s / tau_s)
    out = np.empty_like(v)
    acc = 0.0
    for k in range(v.size):
        acc = a * acc + (1.0 - a) * v[k]
        out[k] = acc
    return out


def dahl_loop(x: np.ndarray, width_m: float) -> np.ndarray:
    """The loop state: from 0, it runs towards +1 while the position rises and towards -1
    while it falls, ``h' = (sgn x' - h) |x'| / width`` (Dahl's friction model, exact over
    each step); rate-independent, so a function of the path alone."""
    out = np.empty_like(x)
    h = 0.0
    out[0] = 0.0
    decay = np.exp(-np.abs(np.diff(x)) / width_m)
    rising = np.diff(x) >= 0.0
    for k in range(decay.size):
        target = 1.0 if rising[k] else -1.0
        h = target + (h - target) * decay[k]
        out[k + 1] = h
    return out


@dataclass
class Block:
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


class LinearProblem:
    """The whitened linear problem around the MAP: residual, sensitivities, force blocks.

    Samples where no trial is counted (gaps, a warm-up) have no innovation: their
    whitened rows are zero, so they add nothing to the sums, and :attr:`n_counted` counts
    the others. The model is simulated from the experiment's estimated ``start`` where it
    has one, and trials on their own inputs enter through the model's trial mean.
    """

    def __init__(self, likelihood: Likelihood, noise, values: dict, sim: Simulation,
                 start: np.ndarray | None = None) -> None:
        self.lik = likelihood
        self.start = start
        self.seen = counted_samples(likelihood)
        self.n_counted = int(np.count_nonzero(self.seen))
        self._gram: dict = {}
        self._folds: list | None = None
        self._targets = None
        self.noise = noise
        self.values = values
        self.sim = sim
        self.model = likelihood.model
        self.dataset = likelihood.dataset
        self.x0 = sim.position_m[0]
        self.n = self.x0.size
        self.r_trials = likelihood.n_trials
        self.plant = linearised_plant(self.model, values, sim, self.dataset.dt_s)
        self.resid = residual(likelihood, self.x0)
        self.r_w = self.whiten(self.resid)
        self.r_w_col = self.r_w[:, None]  # kept: products with it are cached by its id
        self.j_raw, self.j_names = self._sensitivities()
        norms = np.linalg.norm(self.whiten_cols(self.j_raw), axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        self.j = self.j_raw / norms
        self.j_w = self.whiten_cols(self.j)

    def gram(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``u.T @ v``, computed once per pair of arrays."""
        key = (id(u), id(v))
        if key not in self._gram:
            self._gram[key] = (u, v, at_b(u, v))  # the arrays are kept: their ids stay theirs
        return self._gram[key][2]

    @property
    def by_stretches(self) -> bool:
        """Whether the cross-validation leaves out stretches of one record (no repeats)
        instead of trials."""
        return self.r_trials < 2

    def folds(self) -> list[np.ndarray]:
        """The :data:`N_FOLDS` folds of the record: each the sample indices of every
        ``N_FOLDS``-th stretch of it."""
        if self._folds is None:
            edges = np.linspace(0, self.n, N_FOLDS * STRETCHES_PER_FOLD + 1).astype(int)
            stretch = np.repeat(np.arange(edges.size - 1), np.diff(edges))
            self._folds = [np.flatnonzero(stretch % N_FOLDS == k) for k in range(N_FOLDS)]
        return self._folds

    def fold_gram(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``(N_FOLDS, ku, kv)``: ``u[f].T @ v[f]`` over each fold, computed once per pair
        of arrays."""
        key = ("folds", id(u), id(v))
        if key not in self._gram:
            self._gram[key] = (u, v, np.stack([at_b(u[f], v[f]) for f in self.folds()]))
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
        w = self.lik.whiten(v, nz.sigma, nz.rho, nz.white)
        return w if self.seen.all() else np.where(self.seen, w, 0.0)

    def simulate(self, rows: np.ndarray, likelihood: Likelihood | None = None) -> np.ndarray:
        """The model's trial mean ``(batch, n)`` for parameter rows, from the experiment's
        start (of ``likelihood``'s model, the problem's by default)."""
        lik = likelihood or self.lik
        rows = np.atleast_2d(rows)
        start = lik.start_from(self.start, self.lik.model)
        start = None if start is None else np.broadcast_to(start, (rows.shape[0],
                                                                   start.shape[1]))
        return model_mean(lik, lik.simulate(rows, start))

    def whiten_cols(self, cols: np.ndarray) -> np.ndarray:
        return np.stack([self.whiten(c) for c in cols.T], axis=1) if cols.shape[1] else cols

    def _sensitivities(self) -> tuple[np.ndarray, list]:
        model = self.model
        point = dict(model.defaults)
        point.update({k: v for k, v in self.values.items() if k in point})
        names = list(model.free_names)
        rows, steps = _stepped_rows(model, model.theta(point)[0], names)
        x = self.simulate(np.array(rows))
        cols = np.stack([(x[k + 1] - x[0]) / steps[k] for k in range(len(names))], axis=1)
        return cols, names

    def responses(self, forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unwhitened and whitened output responses ``(n, k)`` to force columns ``(n, k)``."""
        g = force_response(self.plant, forces.T).T
        return g, self.whiten_cols(g)

    def states(self, memory_tau_s: float, loop_width_m: float) -> dict:
        """The states along the MAP trajectory, the memory and loop states with the
        given time constant and width."""
        s = self.sim
        v = s.velocity_m_s[0]
        return {"position": s.true_position_m[0], "velocity": v, "pressure": s.pressure_pa[0],
                "hysteresis": s.hysteresis_n[0], "direction": np.sign(v),
                "memory": low_pass(v, memory_tau_s, self.dataset.dt_s),
                "loop": dahl_loop(s.true_position_m[0], loop_width_m)}

    def blocks(self, memory_tau_s: float, loop_width_m: float) -> list[Block]:
        """Each state's block (its spline basis, penalty and responses)."""
        out = []
        for name, series in self.states(memory_tau_s, loop_width_m).items():
            if name == "direction":
                basis, pen, knots, grid = series[:, None].astype(float), np.eye(1), None, (-1, 1)
            else:
                lo, hi = float(np.min(series)), float(np.max(series))
                if not hi > lo:
                    continue  # a state that never changes carries no information
                basis, knots = bspline_design(series, _N_BASIS[name], lo, hi)
                pen, grid = _second_difference(basis.shape[1]), (lo, hi)
            g, gw = self.responses(basis)
            scale = float(np.sqrt(np.mean(np.sum(gw**2, axis=0))))
            scale = scale if scale > 0 else 1.0
            out.append(Block(name, basis, pen, gw / scale, g / scale, scale, knots, grid))
        return out
