"""Yardsticks for the physics: two small black-box models fitted in seconds to the same
training data, predicting the same experiments.

A physics model that predicts held-out data no better than a linear filter has not
earned its parameters. :func:`fit_baselines` fits, on the trial mean of each training
experiment:

``linear``
    A linear output-error model ``y = c + G(s) u``: ``G`` strictly proper of order
    ``n`` (1 to :data:`MAX_LINEAR_ORDER`) with stable poles (first- and second-order
    sections, time constants and damping ratios on a log scale), discretised at each
    data set's own sample interval (zero-order hold) and started in steady state at the
    record's first input. It is fitted by prediction-error minimisation: the model is
    simulated from the input and the output error minimised (variable projection: the
    numerator and the offset by least squares inside, the poles by
    :func:`scipy.optimize.least_squares` outside). ``2 n + 1`` parameters.
``play``
    A Prandtl-Ishlinskii model ``y = c + s (w_0 u + sum_i w_i P_{r_i}[u])``: the input
    itself and ``k`` play (backlash) operators of thresholds spread over half the
    training input's range, weights non-negative (one sign ``s`` for all, the better
    one), offset free; ``k + 2`` parameters. Rate independent.

The order of the linear model and the number of play operators are chosen on the
training data alone: each candidate is fitted on the first :data:`TRAIN_SHARE` of
every training record and scored on the rest (simulated through, so the split is in
time), the one with the smallest error there is refitted on the whole records.

Both take any input (pressure in Pa, force in N): a pressure below a muscle's dead
zone is still a fair input to a linear yardstick, which fits its best line through it.
The numbers compared are those of
:mod:`~pmabayes.criticism.validation`: the RMS error of the trial mean and the NRMSE
(:func:`nrmse`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

from pmabayes.criticism.observed import observed_mean, shared_input
from pmabayes.data import Dataset

__all__ = ["MAX_LINEAR_ORDER", "PLAY_OPERATORS", "TRAIN_SHARE", "LinearBaseline",
           "PlayBaseline", "Baselines", "fit_baselines", "nrmse", "yardstick_text"]

#: Highest order of the linear output-error model.
MAX_LINEAR_ORDER = 4
#: Numbers of play operators tried.
PLAY_OPERATORS = (1, 2, 4, 8)
#: Share of each training record (from its start) the candidates are fitted on when
#: the order or the number of operators is chosen.
TRAIN_SHARE = 0.7


def nrmse(measured_m: np.ndarray, predicted_m: np.ndarray) -> tuple[float, float]:
    """The RMS error of a prediction and its normalised form, over the observed samples.

    Parameters
    ----------
    measured_m : numpy.ndarray
        The measured trial mean (NaN where no trial is observed).
    predicted_m : numpy.ndarray
        The prediction, same shape.

    Returns
    -------
    rmse_m : float
        ``sqrt(mean((measured - predicted)^2))``.
    nrmse : float
        ``rmse_m`` over the RMS of the measurement about its own mean (inf for a
        constant measurement): 0 is perfect, 1 predicts only the mean.
    """
    seen = np.isfinite(measured_m)
    y = measured_m if seen.all() else measured_m[seen]
    resid = y - (predicted_m if seen.all() else predicted_m[seen])
    rmse = float(np.sqrt(np.mean(resid**2)))
    motion = float(np.sqrt(np.mean((y - y.mean()) ** 2)))
    return rmse, (rmse / motion if motion > 0 else math.inf)


@dataclass(frozen=True)
class _Record:
    """One training experiment as the baselines see it: input, trial mean, interval."""

    u: np.ndarray
    y: np.ndarray
    dt_s: float

    @classmethod
    def of(cls, ds: Dataset) -> _Record:
        return cls(shared_input(ds), np.asarray(observed_mean(ds)), float(ds.dt_s))

    def mask(self, part: str) -> np.ndarray:
        """The samples of the fitting part, the held-back part, or all (observed only)."""
        seen = np.isfinite(self.y)
        if part == "all":
            return seen
        cut = int(round(TRAIN_SHARE * self.y.size))
        head = np.arange(self.y.size) < cut
        return seen & (head if part == "head" else ~head)


# ----------------------------------------------------------------------------- linear


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
class LinearBaseline:
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


def fit_linear(records: list) -> LinearBaseline:
    """The linear output-error yardstick, its order chosen on held-back data."""
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


# ----------------------------------------------------------------------------- play


def play(u: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Play (backlash) operators of an input, each started centred on ``u[0]``.

    Parameters
    ----------
    u : numpy.ndarray
        ``(n,)`` input.
    thresholds : numpy.ndarray
        ``(k,)`` half-widths ``r_i`` of the operators, in the input's unit.

    Returns
    -------
    numpy.ndarray
        ``(n, k)``: ``y_t = min(u_t + r, max(u_t - r, y_(t-1)))`` of each.
    """
    r = np.asarray(thresholds, dtype=float)
    out = np.empty((u.size, r.size))
    y = np.full(r.size, float(u[0]))
    for t, ut in enumerate(u):
        y = np.minimum(ut + r, np.maximum(ut - r, y))
        out[t] = y
    return out


@dataclass(frozen=True, eq=False)
class PlayBaseline:
    """A fitted Prandtl-Ishlinskii model (see the module's docstring).

    Parameters
    ----------
    thresholds : numpy.ndarray
        The play operators' half-widths, in the input's unit.
    weights : numpy.ndarray
        ``w_0`` (the input's own) then one per operator, signed (``s w``).
    offset_m : float
        ``c``.
    rmse_m : float
        RMS error on the training data it was fitted to.
    scores : dict
        Candidate number of operators to its RMS error on the held-back part.
    """

    thresholds: np.ndarray
    weights: np.ndarray
    offset_m: float
    rmse_m: float
    scores: dict = field(default_factory=dict)

    @property
    def n_operators(self) -> int:
        """Number of play operators."""
        return int(self.thresholds.size)

    @property
    def n_parameters(self) -> int:
        """Weights and offset."""
        return self.n_operators + 2

    def predict(self, u: np.ndarray, dt_s: float | None = None) -> np.ndarray:
        """The model's output for an input (rate independent: ``dt_s`` is not used).

        Parameters
        ----------
        u : numpy.ndarray
            ``(n,)`` input.
        dt_s : float, optional
            Ignored; for the same call as :meth:`LinearBaseline.predict`.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` position in m.
        """
        u = np.asarray(u, dtype=float)
        return self.offset_m + _play_features(u, self.thresholds) @ self.weights

    def to_dict(self) -> dict:
        """``n_operators``, ``n_parameters``, ``thresholds``, ``weights``, ``offset_m``,
        ``train_rmse_m`` and ``split_rmse_m``."""
        return {"n_operators": self.n_operators, "n_parameters": self.n_parameters,
                "thresholds": [float(v) for v in self.thresholds],
                "weights": [float(v) for v in self.weights], "offset_m": self.offset_m,
                "train_rmse_m": self.rmse_m,
                "split_rmse_m": {str(k): v for k, v in self.scores.items()}}


def _play_features(u: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    return np.concatenate([u[:, None], play(u, thresholds)], axis=1)


def _play_solve(features: list, records: list, masks: list) -> tuple[np.ndarray, float]:
    """Signed non-negative weights and a free offset by least squares: the better sign."""
    a = np.concatenate([f[m] for f, m in zip(features, masks, strict=True)])
    y = np.concatenate([r.y[m] for r, m in zip(records, masks, strict=True)])
    a = np.concatenate([a, np.ones((a.shape[0], 1))], axis=1)
    norms = np.linalg.norm(a, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    lower = np.r_[np.zeros(a.shape[1] - 1), -np.inf]
    best = None
    for sign in (1.0, -1.0):
        scale = np.r_[np.full(a.shape[1] - 1, sign), 1.0] / norms
        sol = optimize.lsq_linear(a * scale, y, bounds=(lower, np.inf), method="bvls")
        coef = sol.x * scale
        cost = float(np.sum((y - a @ coef) ** 2))
        if best is None or cost < best[1]:
            best = (coef, cost)
    return best[0][:-1], float(best[0][-1])


def fit_play(records: list) -> PlayBaseline:
    """The Prandtl-Ishlinskii yardstick, its number of operators chosen on held-back data."""
    lo = min(float(np.min(r.u)) for r in records)
    hi = max(float(np.max(r.u)) for r in records)
    half = 0.5 * (hi - lo) if hi > lo else 1.0
    heads = [r.mask("head") for r in records]
    scores, fitted = {}, {}
    for k in PLAY_OPERATORS:
        thresholds = half * np.arange(1, k + 1) / (k + 1)
        feats = [_play_features(r.u, thresholds) for r in records]
        w, c = _play_solve(feats, records, heads)
        err = np.concatenate([r.y[r.mask("tail")] - (f @ w + c)[r.mask("tail")]
                              for r, f in zip(records, feats, strict=True)])
        scores[k] = float(np.sqrt(np.mean(err**2))) if err.size else math.inf
        fitted[k] = (thresholds, feats)
    k = min(scores, key=scores.get)
    thresholds, feats = fitted[k]
    masks = [r.mask("all") for r in records]
    w, c = _play_solve(feats, records, masks)
    err = np.concatenate([r.y[m] - (f @ w + c)[m] for r, f, m in zip(records, feats, masks,
                                                                      strict=True)])
    return PlayBaseline(thresholds=thresholds, weights=w, offset_m=c,
                        rmse_m=float(np.sqrt(np.mean(err**2))), scores=scores)


# ----------------------------------------------------------------------------- both


@dataclass(frozen=True, eq=False)
class Baselines:
    """The two yardsticks fitted to one set of training experiments.

    Parameters
    ----------
    linear : LinearBaseline
    play : PlayBaseline
    seconds : float
        Wall time of both fits.
    trained_on : list of str
        The training experiments' sources (or names).
    """

    linear: LinearBaseline
    play: PlayBaseline
    seconds: float
    trained_on: list

    def predict(self, dataset: Dataset) -> dict[str, np.ndarray]:
        """Each yardstick's prediction of a data set's trial mean from its input.

        Parameters
        ----------
        dataset : Dataset

        Returns
        -------
        dict
            ``"linear"`` and ``"play"`` to ``(n_samples,)`` positions in m.
        """
        u = shared_input(dataset)
        return {"linear": self.linear.predict(u, dataset.dt_s),
                "play": self.play.predict(u, dataset.dt_s)}

    def scores(self, dataset: Dataset, *, arrays: bool = False) -> dict:
        """Each yardstick's errors on a data set: the JSON entry ``baselines``.

        Parameters
        ----------
        dataset : Dataset
            The experiment predicted.
        arrays : bool
            Include each prediction (``prediction_m``).

        Returns
        -------
        dict
            ``"linear"`` and ``"play"``, each with ``rmse_m``, ``nrmse`` and its own
            description (:meth:`LinearBaseline.to_dict`, :meth:`PlayBaseline.to_dict`).
        """
        ybar = observed_mean(dataset)
        out = {}
        for name, pred in self.predict(dataset).items():
            rmse, nr = nrmse(ybar, pred)
            out[name] = {"rmse_m": rmse, "nrmse": nr,
                         **getattr(self, name).to_dict(),
                         **({"prediction_m": pred} if arrays else {})}
        return out


def fit_baselines(datasets: Dataset | Sequence[Dataset]) -> Baselines:
    """Fit the linear output-error and the Prandtl-Ishlinskii yardsticks to training data.

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        The training experiments (one input each; their trial means are fitted).

    Returns
    -------
    Baselines

    Raises
    ------
    ValueError
        Without a training experiment, or when no sample is observed.
    """
    dss = [datasets] if isinstance(datasets, Dataset) else list(datasets)
    if not dss:
        raise ValueError("the baselines need at least one training experiment")
    records = [_Record.of(ds) for ds in dss]
    if not any(r.mask("all").any() for r in records):
        raise ValueError("the training experiments have no observed sample")
    start = time.perf_counter()
    linear = fit_linear(records)
    pi = fit_play(records)
    return Baselines(linear=linear, play=pi, seconds=time.perf_counter() - start,
                     trained_on=[str(ds.source or f"experiment {i + 1}")
                                 for i, ds in enumerate(dss)])


def yardstick_text(physics: dict[str, float], baselines: dict[str, dict], *,
                   metric: str = "nrmse", where: str = "") -> str:
    """A plain sentence when the physics does not beat a yardstick; empty when it beats both.

    Parameters
    ----------
    physics : dict
        The physics model's ``{"rmse_m", "nrmse"}`` on the same data.
    baselines : dict
        :meth:`Baselines.scores` of those data.
    metric : str
        ``"nrmse"`` or ``"rmse_m"``, the number compared.
    where : str
        What the numbers are on (``"on held-out data"``, ``"on the training record"``).

    Returns
    -------
    str
    """
    ours = physics[metric]
    beaten = [(n, b) for n, b in baselines.items() if not ours < b[metric]]
    if not beaten:
        return ""

    def num(v: float) -> str:
        return f"{v * 1e6:.4g} µm" if metric == "rmse_m" else f"{v:.3g}"

    label = {"linear": "a linear output-error model of order {order} ({n} parameters)",
             "play": "a Prandtl-Ishlinskii model of {k} play operator(s) ({n} parameters)"}
    parts = [label[n].format(order=b.get("order"), k=b.get("n_operators"),
                             n=b.get("n_parameters")) + f", {num(b[metric])}"
             for n, b in beaten]
    what = "RMS error" if metric == "rmse_m" else "NRMSE"
    return (f"The physics does not beat the yardstick{'s' if len(beaten) > 1 else ''}"
            f"{' ' + where if where else ''}: its {what} is {num(ours)}, against "
            + " and ".join(parts) + "; the model has not earned its parameters there.")
