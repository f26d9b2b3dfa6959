"""The linear output-error yardstick ``y = c + G(s) u``.

``G`` is strictly proper of order ``n`` (1 to :data:`MAX_LINEAR_ORDER`) with stable
poles (first- and second-order sections, time constants and damping ratios on a log
scale), discretised at each data set's own sample interval (zero-order hold) and started
in steady state at the record's first input. It is fitted by prediction-error
minimisation: the model is simulated from the input and the output error minimised
(variable projection: the numerator and the offset by least squares inside, the poles
by :func:`scipy.optimize.least_squares` outside). ``2 n + 1`` parameters. The order is
chosen on the training data alone: each is fitted on the first
:data:`~pmabayes.criticism.yardsticks.base.TRAIN_SHARE` of every training record and
scored on the rest (simulated through, so the split is in time); the best is refitted
on the whole records.

It takes any input (pressure in Pa, force in N): a pressure below a muscle's dead zone
is still a fair input to a linear yardstick, which fits its best line through it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

from pmabayes.criticism.observed import shared_input
from pmabayes.criticism.yardsticks.base import Fitted, Record, Yardstick
from pmabayes.data import Dataset

__all__ = ["MAX_LINEAR_ORDER", "LinearBaseline", "LinearYardstick", "fit_linear"]

#: Highest order of the linear output-error model.
MAX_LINEAR_ORDER = 4


def _denominator(sections: Sequence[tuple[str, float, float | None]]) -> np.ndarray:
    """``D(s)`` (highest power first, ``D(0) = 1``) of first-order sections ``T s + 1``
    and second-order sections ``s^2 / w^2 + 2 zeta s / w + 1``."""
    den = np.array([1.0])
    for kind, a, b in sections:
        if kind == "first":
            den = np.polymul(den, [a, 1.0])
        else:
            den = np.polymul(den, [1.0 / (a * a), 2.0 * b / a, 1.0])
    return den


def _sections(order: int, theta: np.ndarray) -> list:
    """Sections of an order from log parameters: second-order ones first (log w, log zeta),
    then one first-order (log T) for an odd order."""
    out = [("second", math.exp(theta[2 * i]), math.exp(theta[2 * i + 1]))
           for i in range(order // 2)]
    if order % 2:
        out.append(("first", math.exp(theta[-1]), None))
    return out


def _expm(m: np.ndarray) -> np.ndarray:
    """The exponential of a small matrix: Taylor series after scaling, then squaring
    (scipy's expm is slowed a thousandfold by BLAS threads on a busy machine)."""
    norm = float(np.max(np.sum(np.abs(m), axis=1)))
    squarings = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    a = m / 2.0**squarings
    out = term = np.eye(m.shape[0])
    for k in range(1, 16):
        term = term @ a / k
        out = out + term
    for _ in range(squarings):
        out = out @ out
    return out


def _basis(den: np.ndarray, u: np.ndarray, dt_s: float) -> np.ndarray:
    """``(n, order)``: the responses ``s^j / D(s)`` to ``u`` (zero-order hold), each started
    in steady state at ``u[0]``."""
    order = den.size - 1
    a = den / den[0]
    comp = np.zeros((order + 1, order + 1))
    comp[:order - 1, 1:order] = np.eye(order - 1)
    comp[order - 1, :order] = -a[::-1][:order]
    comp[order - 1, order] = 1.0 / den[0]
    ad_bd = _expm(comp * dt_s)
    ad, bd = ad_bd[:order, :order], ad_bd[:order, order]
    du = u - u[0]
    num, dd = signal.ss2tf(ad, bd[:, None], np.eye(order), np.zeros((order, 1)))
    cols = np.stack([signal.lfilter(num[j], dd, du) for j in range(order)], axis=1)
    cols[:, 0] += u[0]  # the steady state of 1 / D(s), D(0) = 1
    return cols


@dataclass(frozen=True, eq=False)
class LinearBaseline(Fitted):
    """A fitted linear output-error model (see the module's docstring).

    Parameters
    ----------
    order : int
        Order of ``G(s)`` (its number of poles).
    sections : list
        ``("first", T_s, None)`` and ``("second", omega_rad_s, zeta)`` factors of the
        denominator.
    numerator : numpy.ndarray
        Coefficients of ``s^0 ... s^(order - 1)`` over ``D(s)``, per unit input.
    offset_m : float
        ``c``.
    rmse_m : float
        RMS error on the training data it was fitted to.
    scores : dict
        Candidate order to its RMS error on the held-back part of the training data.
    """

    name = "linear"

    order: int
    sections: list
    numerator: np.ndarray
    offset_m: float
    rmse_m: float
    scores: dict = field(default_factory=dict)

    @property
    def n_parameters(self) -> int:
        """``2 order + 1``: poles, numerator and offset."""
        return 2 * self.order + 1

    def predict(self, u: np.ndarray, dt_s: float) -> np.ndarray:
        """The model's output for an input sampled every ``dt_s`` seconds.

        Parameters
        ----------
        u : numpy.ndarray
            ``(n,)`` input.
        dt_s : float
            Its sample interval.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` position in m.
        """
        return self.offset_m + _basis(_denominator(self.sections), np.asarray(u, float),
                                      dt_s) @ self.numerator

    def predict_dataset(self, dataset: Dataset) -> np.ndarray:
        """The predicted trial mean of a data set (:meth:`predict` of its input)."""
        return self.predict(shared_input(dataset), dataset.dt_s)

    def poles_hz(self) -> list[float]:
        """The poles' natural frequencies in Hz (``1 / (2 pi T)`` of a first-order one)."""
        return sorted((1.0 / (2 * math.pi * a) if k == "first" else a / (2 * math.pi))
                      for k, a, _ in self.sections)

    def to_dict(self) -> dict:
        """``order``, ``n_parameters``, ``poles_hz``, ``damping`` (of each second-order
        section), ``offset_m``, ``train_rmse_m`` and ``split_rmse_m`` (order to error)."""
        return {"order": self.order, "n_parameters": self.n_parameters,
                "poles_hz": self.poles_hz(),
                "damping": [b for k, _, b in self.sections if k == "second"],
                "offset_m": self.offset_m, "train_rmse_m": self.rmse_m,
                "split_rmse_m": {str(k): v for k, v in self.scores.items()}}


def _linear_solve(records: list, masks: list, order: int, theta: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, float]:
    """Numerator and offset by least squares for given poles: the residual over the masked
    samples, the coefficients (numerator, then offset) and the offset."""
    y = np.concatenate([rec.y[m] for rec, m in zip(records, masks, strict=True)])
    worst = (np.full(y.size, 1e3 * (np.std(y) + 1.0)), np.zeros(order + 1), 0.0)
    if not np.all(np.abs(theta) < 40.0):  # a pole the search flung out of all reason
        return worst
    den = _denominator(_sections(order, theta))
    rows = []
    try:
        with np.errstate(all="ignore"):
            for rec, m in zip(records, masks, strict=True):
                b = _basis(den, rec.u, rec.dt_s)
                rows.append(np.concatenate([b, np.ones((b.shape[0], 1))], axis=1)[m])
    except (ValueError, ZeroDivisionError):  # numpy's LinAlgError is a ValueError
        return worst
    a = np.concatenate(rows)
    if not np.all(np.isfinite(a)):
        return worst
    norms = np.linalg.norm(a, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    coef = np.linalg.lstsq(a / norms, y, rcond=None)[0] / norms
    return y - a @ coef, coef, float(coef[-1])


def _scan_times(records: list) -> np.ndarray:
    dt = min(r.dt_s for r in records)
    span = max(r.dt_s * (r.y.size - 1) for r in records)
    return np.geomspace(3.0 * dt, max(span / 3.0, 10.0 * dt), 10)


def _starts(order: int, previous: np.ndarray | None, records: list) -> list[np.ndarray]:
    """Starting points of an order: a scan for order 1 and 2, then the lower order's
    optimum with one more pole scanned."""
    times = np.log(_scan_times(records))
    if order == 1:
        return [np.array([t]) for t in times]
    if order == 2:
        out = [np.array([-t, math.log(z)]) for t in times for z in (0.3, 1.0, 3.0)]
        if previous is not None:  # the first-order optimum with a second, faster real pole
            t1 = math.exp(previous[0])
            for t2 in np.exp(times):
                w = 1.0 / math.sqrt(t1 * t2)
                out.append(np.array([math.log(w), math.log((t1 + t2) * w / 2.0)]))
        return out
    if order == 3:
        return [np.concatenate([previous, [t]]) for t in times]
    t1 = math.exp(previous[-1])  # order 4: the third-order's real pole paired with a new one
    out = []
    for t2 in np.exp(times):
        w = 1.0 / math.sqrt(t1 * t2)
        out.append(np.concatenate([previous[:2], [math.log(w), math.log((t1 + t2) * w / 2.0)]]))
    return out


def _fit_order(records: list, masks: list, order: int, previous: np.ndarray | None
               ) -> tuple[np.ndarray, float]:
    """The poles of one order minimising the output error: the best start of a scan,
    polished by least squares."""
    def resid(theta):
        return _linear_solve(records, masks, order, theta)[0]

    def cost(theta):
        r = resid(theta)
        return float(r @ r)

    start = min(_starts(order, previous, records), key=cost)
    best = _polish(resid, start, order)
    r = resid(best)
    return best, float(np.sqrt(np.mean(r**2)))


def _polish(resid, start: np.ndarray, order: int) -> np.ndarray:
    """Levenberg-Marquardt on the projected output error from a start; the start when it
    does not improve on it."""
    with np.errstate(all="ignore"):
        sol = optimize.least_squares(resid, start, method="lm", max_nfev=40 * (order + 1),
                                     diff_step=1e-4)
    r0 = resid(start)
    return sol.x if np.isfinite(sol.cost) and sol.cost <= 0.5 * float(r0 @ r0) else start


def _held_back_rmse(records: list, order: int, theta: np.ndarray) -> float:
    """Error on the held-back tails, the model fitted (numerator and offset too) on the
    heads."""
    _, coef, _ = _linear_solve(records, [r.mask("head") for r in records], order, theta)
    den = _denominator(_sections(order, theta))
    errs = []
    for rec in records:
        m = rec.mask("tail")
        pred = _basis(den, rec.u, rec.dt_s) @ coef[:-1] + coef[-1]
        errs.append(rec.y[m] - pred[m])
    e = np.concatenate(errs)
    return float(np.sqrt(np.mean(e**2))) if e.size else math.inf


def fit_linear(records: Sequence[Record]) -> LinearBaseline:
    """The linear output-error yardstick, its order chosen on held-back data.

    Parameters
    ----------
    records : sequence of Record
        The training experiments.

    Returns
    -------
    LinearBaseline
    """
    heads = [r.mask("head") for r in records]
    scores, thetas, previous = {}, {}, None
    for order in range(1, MAX_LINEAR_ORDER + 1):
        theta, _ = _fit_order(records, heads, order, previous)
        thetas[order], previous = theta, theta
        scores[order] = _held_back_rmse(records, order, theta)
    finite = {k: v for k, v in scores.items() if math.isfinite(v)}
    order = min(finite, key=finite.get) if finite else 1
    masks = [r.mask("all") for r in records]
    # the split's optimum polished on the whole records
    theta = _polish(lambda th: _linear_solve(records, masks, order, th)[0], thetas[order], order)
    r, coef, offset = _linear_solve(records, masks, order, theta)
    return LinearBaseline(order=order, sections=_sections(order, theta),
                          numerator=coef[:-1].copy(), offset_m=offset,
                          rmse_m=float(np.sqrt(np.mean(r**2))), scores=scores)



class LinearYardstick(Yardstick):
    """The linear output-error yardstick (see the module's docstring)."""

    name = "linear"
    colour = "tab:green"
    kind = "a linear output-error model"
    order_words = "order {order}"

    def fit(self, records: Sequence[Record]) -> LinearBaseline:
        """:func:`fit_linear`."""
        return fit_linear(list(records))

