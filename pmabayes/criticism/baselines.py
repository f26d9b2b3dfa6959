"""Yardsticks for the physics: small black-box models fitted in seconds to the same
training data, predicting the same experiments.

A physics model that predicts held-out data no better than a linear filter has not
earned its parameters. :func:`fit_baselines` fits every yardstick of
:mod:`pmabayes.criticism.yardsticks` on the trial mean of each training experiment:

``linear``
    A linear output-error model ``y = c + G(s) u`` of order 1 to 4
    (:mod:`~pmabayes.criticism.yardsticks.linear`).
``play``
    A Prandtl-Ishlinskii model: the input and 1, 2, 4 or 8 play operators
    (:mod:`~pmabayes.criticism.yardsticks.play`).
``narx``
    A polynomial NARX model of degree 2 with lags 1 to 4, its terms chosen by forward
    regression with orthogonal least squares (FROLS, built in;
    :mod:`~pmabayes.criticism.yardsticks.narx`).

Each chooses its order on the training data alone: each candidate is fitted on the
first :data:`TRAIN_SHARE` of every training record and scored on the rest (simulated
through, so the split is in time), and the one with the smallest error there is refitted
on the whole records. Each predicts by free-run simulation from the input alone.

They take any input (pressure in Pa, force in N). The numbers compared are those of
:mod:`~pmabayes.criticism.validation`: the RMS error of the trial mean and the NRMSE
(:func:`nrmse`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pmabayes.criticism.observed import observed_mean
from pmabayes.criticism.yardsticks import (
    MAX_LINEAR_ORDER,
    PLAY_OPERATORS,
    REGISTRY,
    TRAIN_SHARE,
    Fitted,
    LeftOut,
    LinearBaseline,
    PlayBaseline,
    PredictionFailed,
    Record,
    nrmse,
)
from pmabayes.criticism.yardsticks.play import play
from pmabayes.data import Dataset

__all__ = ["MAX_LINEAR_ORDER", "PLAY_OPERATORS", "TRAIN_SHARE", "LinearBaseline",
           "PlayBaseline", "Baselines", "fit_baselines", "nrmse", "play", "yardstick_text"]


@dataclass(frozen=True, eq=False)
class Baselines:
    """The yardsticks fitted to one set of training experiments.

    Parameters
    ----------
    fitted : dict
        Name (``"linear"``, ``"play"``, ``"narx"``) to its
        :class:`~pmabayes.criticism.yardsticks.base.Fitted`, in the registry's order.
    seconds : float
        Wall time of the fits.
    trained_on : list of str
        The training experiments' sources (or names).
    left_out : dict
        Name to the one line saying why it was not fitted (records too short for it, every
        candidate's free run diverging).
    """

    fitted: dict
    seconds: float
    trained_on: list
    left_out: dict = field(default_factory=dict)

    @property
    def linear(self) -> LinearBaseline | None:
        """The linear output-error yardstick."""
        return self.fitted.get("linear")

    @property
    def play(self) -> PlayBaseline | None:
        """The Prandtl-Ishlinskii yardstick."""
        return self.fitted.get("play")

    def predict(self, dataset: Dataset) -> dict[str, np.ndarray]:
        """Each yardstick's prediction of a data set's trial mean from its input.

        Parameters
        ----------
        dataset : Dataset

        Returns
        -------
        dict
            Name to ``(n_samples,)`` positions in m; NaN throughout for a yardstick that
            cannot predict it (:meth:`scores` says why).
        """
        return {name: self._predict(f, dataset)[0] for name, f in self.fitted.items()}

    @staticmethod
    def _predict(fitted: Fitted, dataset: Dataset) -> tuple[np.ndarray, str | None]:
        try:
            return fitted.predict_dataset(dataset), None
        except PredictionFailed as err:
            return np.full(dataset.n_samples, np.nan), str(err)

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
            Name to ``rmse_m``, ``nrmse``, ``order_text`` and its own description
            (:meth:`~pmabayes.criticism.yardsticks.base.Fitted.to_dict`). A yardstick
            that cannot predict the data set (its free run diverges) has ``rmse_m`` and
            ``nrmse`` inf and ``failed``, the reason.
        """
        ybar = observed_mean(dataset)
        out = {}
        for name, fitted in self.fitted.items():
            pred, failed = self._predict(fitted, dataset)
            rmse, nr = (math.inf, math.inf) if failed else nrmse(ybar, pred)
            out[name] = {"rmse_m": rmse, "nrmse": nr, "order_text": fitted.order_text(),
                         **({"failed": failed} if failed else {}),
                         **fitted.to_dict(),
                         **({"prediction_m": pred} if arrays else {})}
        return out

    def lines(self) -> list[str]:
        """One line per yardstick left out, with the reason and the fix."""
        return [reason for reason in self.left_out.values()]

    def to_dict(self) -> dict:
        """``trained_on``, ``seconds``, ``fitted`` (the names and their orders in words)
        and ``left_out`` (name to the reason)."""
        return {"trained_on": list(self.trained_on), "seconds": self.seconds,
                "fitted": {n: f.order_text() for n, f in self.fitted.items()},
                "left_out": dict(self.left_out)}


def fit_baselines(datasets: Dataset | Sequence[Dataset]) -> Baselines:
    """Fit every registered yardstick (linear output-error, Prandtl-Ishlinskii,
    polynomial NARX) to training data.

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        The training experiments (one input each; their trial means are fitted).

    Returns
    -------
    Baselines
        A yardstick that cannot be fitted here (records too short for it, every
        candidate's free run diverging) is in ``left_out`` with the reason, not an error.

    Raises
    ------
    ValueError
        Without a training experiment, or when no sample is observed.
    """
    dss = [datasets] if isinstance(datasets, Dataset) else list(datasets)
    if not dss:
        raise ValueError("the baselines need at least one training experiment")
    names = [str(ds.source or f"experiment {i + 1}") for i, ds in enumerate(dss)]
    records = [Record.of(ds, name) for ds, name in zip(dss, names, strict=True)]
    if not any(r.mask("all").any() for r in records):
        raise ValueError("the training experiments have no observed sample")
    start = time.perf_counter()
    fitted, left_out = {}, {}
    for name, kind in REGISTRY.items():
        reason = kind.unavailable()
        if reason is None:
            try:
                fitted[name] = kind().fit(records)
            except LeftOut as err:
                reason = str(err)
        if reason is not None:
            left_out[name] = reason
    return Baselines(fitted=fitted, seconds=time.perf_counter() - start, trained_on=names,
                     left_out=left_out)


def yardstick_text(physics: dict[str, float], baselines: dict[str, dict], *,
                   metric: str = "nrmse", where: str = "") -> str:
    """A plain sentence when the physics does not beat a yardstick; empty when it beats all.

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

    parts = [REGISTRY[n].describe(b) + f", {num(b[metric])}" for n, b in beaten]
    what = "RMS error" if metric == "rmse_m" else "NRMSE"
    return (f"The physics does not beat the yardstick{'s' if len(beaten) > 1 else ''}"
            f"{' ' + where if where else ''}: its {what} is {num(ours)}, against "
            + " and ".join(parts) + "; the model has not earned its parameters there.")
