"""The Prandtl-Ishlinskii yardstick ``y = c + s (w_0 u + sum_i w_i P_{r_i}[u])``.

The input itself and ``k`` play (backlash) operators of thresholds spread over half the
training input's range, weights non-negative (one sign ``s`` for all, the better one),
offset free; ``k + 2`` parameters. Rate independent. The number of operators (one of
:data:`PLAY_OPERATORS`) is chosen on the training data alone: each is fitted on the
first :data:`~pmabayes.criticism.yardsticks.base.TRAIN_SHARE` of every training record
and scored on the rest; the best is refitted on the whole records.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from pmabayes.criticism.observed import shared_input
from pmabayes.criticism.yardsticks.base import Fitted, Record, Yardstick
from pmabayes.data import Dataset

__all__ = ["PLAY_OPERATORS", "PlayBaseline", "PlayYardstick", "fit_play", "play"]

#: Numbers of play operators tried.
PLAY_OPERATORS = (1, 2, 4, 8)


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
class PlayBaseline(Fitted):
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

    name = "play"

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
            Ignored; for the same call as
            :meth:`~pmabayes.criticism.yardsticks.linear.LinearBaseline.predict`.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` position in m.
        """
        u = np.asarray(u, dtype=float)
        return self.offset_m + _play_features(u, self.thresholds) @ self.weights

    def predict_dataset(self, dataset: Dataset) -> np.ndarray:
        """The predicted trial mean of a data set (:meth:`predict` of its input)."""
        return self.predict(shared_input(dataset))

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


def fit_play(records: Sequence[Record]) -> PlayBaseline:
    """The Prandtl-Ishlinskii yardstick, its number of operators chosen on held-back data.

    Parameters
    ----------
    records : sequence of Record
        The training experiments, as for
        :func:`~pmabayes.criticism.yardsticks.linear.fit_linear`.

    Returns
    -------
    PlayBaseline
    """
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



class PlayYardstick(Yardstick):
    """The Prandtl-Ishlinskii yardstick (see the module's docstring)."""

    name = "play"
    colour = "tab:purple"
    kind = "a Prandtl-Ishlinskii model"
    order_words = "{n_operators} play operator(s)"

    def fit(self, records: Sequence[Record]) -> PlayBaseline:
        """:func:`fit_play`."""
        return fit_play(list(records))

