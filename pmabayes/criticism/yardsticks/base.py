"""What every yardstick is: a black-box model fitted in seconds to the training data's
trial means, choosing its own order on the training data alone, and predicting a data
set's trial mean from its input by free-run simulation.

A yardstick is one subclass of :class:`Yardstick` (its ``name``, ``fit`` and
``describe``) whose ``fit`` returns a :class:`Fitted` (``predict``, ``order_text``,
``to_dict``); defining the class registers it (:data:`REGISTRY`), and
:func:`~pmabayes.criticism.baselines.fit_baselines` fits every registered one.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from pmabayes.criticism.observed import observed_mean, shared_input
from pmabayes.data import Dataset

__all__ = ["TRAIN_SHARE", "REGISTRY", "Record", "Fitted", "Yardstick", "LeftOut",
           "PredictionFailed", "nrmse"]

#: Share of each training record (from its start) the candidates are fitted on when
#: a yardstick's order is chosen; the rest is simulated through and scored.
TRAIN_SHARE = 0.7

#: The yardsticks, by name, in the order they are defined (linear, play, narx).
#:
#: :meta hide-value:
REGISTRY: dict[str, type[Yardstick]] = {}


class LeftOut(Exception):  # noqa: N818 (a verdict, not an error of the caller's)
    """A yardstick that cannot be fitted to these training data (a missing optional
    dependency, records too short for its smallest order): it is left out, and the
    message, one line naming the file and the fix, says why."""


class PredictionFailed(Exception):  # noqa: N818
    """A fitted yardstick that cannot predict a data set (its free-run simulation
    diverges, a condition it needs is not declared): its error there is infinite, and
    the message says why."""


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


def declared_load_kg(dataset: Dataset) -> float | None:
    """The moving mass a data set's rig declares (its sidecar's ``rig.moving_mass_kg``,
    the dead load of a hanging muscle), in kg; None when it declares none or a prior
    instead of a number."""
    rig = dataset.metadata.get("rig")
    value = rig.get("moving_mass_kg") if isinstance(rig, dict) else None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) \
        else None


@dataclass(frozen=True)
class Record:
    """One experiment as the yardsticks see it: input, trial mean, sample interval, where
    it came from and its declared load.

    Parameters
    ----------
    u : numpy.ndarray
        ``(n,)`` input (:func:`~pmabayes.criticism.observed.shared_input`).
    y : numpy.ndarray
        ``(n,)`` trial mean in m, NaN where no trial is observed.
    dt_s : float
        Sample interval.
    source : str
        The file (or the experiment's name) for messages.
    load_kg : float or None
        :func:`declared_load_kg`.
    """

    u: np.ndarray
    y: np.ndarray
    dt_s: float
    source: str = "experiment"
    load_kg: float | None = None

    @classmethod
    def of(cls, ds: Dataset, name: str = "experiment") -> Record:
        """The record of a data set (``name`` where it has no source)."""
        return cls(shared_input(ds), np.asarray(observed_mean(ds)), float(ds.dt_s),
                   str(ds.source or name), declared_load_kg(ds))

    def mask(self, part: str) -> np.ndarray:
        """The samples of the fitting part (``"head"``), the held-back part
        (``"tail"``), or ``"all"`` (observed only)."""
        seen = np.isfinite(self.y)
        if part == "all":
            return seen
        cut = int(round(TRAIN_SHARE * self.y.size))
        head = np.arange(self.y.size) < cut
        return seen & (head if part == "head" else ~head)


class Fitted(ABC):
    """A yardstick fitted to training data.

    Subclasses hold ``rmse_m`` (the error on the records fitted) and ``scores`` (each
    candidate order's error on the held-back parts) and define the members below.
    """

    #: The yardstick's name (:attr:`Yardstick.name`).
    name: ClassVar[str]

    @property
    @abstractmethod
    def n_parameters(self) -> int:
        """Number of fitted parameters."""

    @abstractmethod
    def predict_dataset(self, dataset: Dataset) -> np.ndarray:
        """The predicted trial mean of a data set from its input, in m.

        Parameters
        ----------
        dataset : Dataset

        Returns
        -------
        numpy.ndarray
            ``(n_samples,)``.

        Raises
        ------
        PredictionFailed
            When it cannot be predicted (a diverging simulation, a condition missing).
        """

    @abstractmethod
    def to_dict(self) -> dict:
        """The fitted model for JSON: its orders (``n_parameters`` and its own),
        ``train_rmse_m`` and ``split_rmse_m`` (candidate to held-back error)."""

    def order_text(self) -> str:
        """Its orders in a few words, for the printout and the report."""
        return REGISTRY[self.name].orders(self.to_dict())


class Yardstick(ABC):
    """One kind of yardstick: defining a subclass with a ``name`` registers it.

    Subclasses define :attr:`name`, :attr:`colour`, :meth:`fit`, and the words that
    name it (:attr:`kind`, :attr:`order_words`, :attr:`size_words`);
    :meth:`unavailable` when it needs an optional package.

    Examples
    --------
    A static line of position on input, the crudest yardstick, registered beside the
    built-in ones and forgotten again:

    >>> import numpy as np
    >>> from pmabayes.criticism.baselines import fit_baselines
    >>> from pmabayes.criticism.observed import shared_input
    >>> from pmabayes.criticism.yardsticks import REGISTRY, Fitted, Yardstick
    >>> class StaticLine(Fitted):
    ...     name = "static_line"
    ...     n_parameters = 2
    ...     def __init__(self, gain, offset_m, rmse_m):
    ...         self.gain, self.offset_m, self.rmse_m, self.scores = gain, offset_m, rmse_m, {}
    ...     def predict_dataset(self, dataset):
    ...         return self.gain * shared_input(dataset) + self.offset_m
    ...     def to_dict(self):
    ...         return {"n_parameters": 2, "train_rmse_m": self.rmse_m}
    >>> class StaticLineYardstick(Yardstick):
    ...     name = "static_line"
    ...     def fit(self, records):
    ...         u = np.concatenate([r.u[r.mask("all")] for r in records])
    ...         y = np.concatenate([r.y[r.mask("all")] for r in records])
    ...         (gain, offset_m), *_ = np.linalg.lstsq(np.c_[u, np.ones_like(u)], y)
    ...         rmse_m = float(np.sqrt(np.mean((gain * u + offset_m - y) ** 2)))
    ...         return StaticLine(gain, offset_m, rmse_m)
    ...     kind = "a static line of position on input"
    ...     order_words = "no dynamics"
    >>> from pmabayes.synthetic import example_data
    >>> data = example_data()  # three synthetic 4 s chirps at 200 Hz
    >>> fitted = fit_baselines(data)
    >>> list(fitted.fitted)
    ['linear', 'play', 'narx', 'static_line']
    >>> scores = fitted.scores(data)
    >>> bool(scores["static_line"]["nrmse"] > scores["linear"]["nrmse"])  # it misses the dynamics
    True
    >>> del REGISTRY["static_line"]
    """

    #: Key of the JSON entry (``baselines.<name>``) and of :data:`REGISTRY`.
    name: ClassVar[str]
    #: Colour of its prediction in the figures.
    colour: ClassVar[str] = "k"
    #: What it is, for the report (``"a linear output-error model"``).
    kind: ClassVar[str] = "a black-box model"
    #: Its chosen orders, a format string over its JSON entry (``"order {order}"``).
    order_words: ClassVar[str] = "its own orders"
    #: Its size, likewise (the number of fitted parameters by default).
    size_words: ClassVar[str] = "{n_parameters} parameters"

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if getattr(cls, "name", None):
            REGISTRY[cls.name] = cls

    @classmethod
    def unavailable(cls) -> str | None:
        """Why it cannot be fitted on this installation (one line with the fix); None
        when it can."""
        return None

    @abstractmethod
    def fit(self, records: Sequence[Record]) -> Fitted:
        """Fit it to the training records, its order chosen on them alone.

        Parameters
        ----------
        records : sequence of Record

        Returns
        -------
        Fitted

        Raises
        ------
        LeftOut
            When these records cannot fit it (the message names the file and the fix).
        """

    @classmethod
    def orders(cls, entry: dict) -> str:
        """Its orders in a few words (``"order 2, 5 parameters"``) from its JSON entry
        (:meth:`Fitted.to_dict`): :attr:`order_words` and :attr:`size_words` filled in."""
        return f"{_fill(cls.order_words, entry)}, {_fill(cls.size_words, entry)}"

    @classmethod
    def describe(cls, entry: dict) -> str:
        """What it is, in words, from its JSON entry (``"a linear output-error model of
        order 2 (5 parameters)"``): :attr:`kind` of its orders."""
        return (f"{cls.kind} of {_fill(cls.order_words, entry)} "
                f"({_fill(cls.size_words, entry)})")


class _Entry(dict):
    def __missing__(self, key: str) -> None:
        return None


def _fill(words: str, entry: dict) -> str:
    return words.format_map(_Entry(entry))
