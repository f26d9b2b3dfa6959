"""The interface of a noise model, and the registry that names them.

A noise model says how the data scatter about the model's positions: its parameters
(with priors; their transform follows from the prior, as for the model's), the log
density of residual series (some samples possibly not observed), their whitening, and
draws of noise series. :class:`pmabayes.inference.likelihood.Likelihood` delegates all
of these to its noise model object; a new model is one module that subclasses
:class:`NoiseModel` and registers itself (:func:`register_noise_model`), then its name
is a value of ``noise_model`` (:class:`pmabayes.inference.FitSettings`, ``--noise-model``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar

import numpy as np

if TYPE_CHECKING:  # the likelihood holds a noise model: imported for types only
    from pmabayes.inference.likelihood import Likelihood
    from pmabayes.model.parameters import Parameter

__all__ = ["NoiseModel", "register_noise_model", "noise_model_class", "registered_noise_models"]


class NoiseModel(ABC):
    """How one trial's data scatter about the model: the likelihood's noise.

    Every method works on residual series ``scale * (y[m] - x[b, m or 0])``: ``y``
    ``(series, n)`` are data (trials, the trial mean, contrasts), ``x`` ``(batch or 1,
    1 or series, n)`` the model's positions, and ``noise`` the noise parameters as
    :meth:`parameters` lists them, each broadcast to ``(batch,)``.

    Attributes
    ----------
    name : str
        The registry's key, the value of ``noise_model`` that selects it.
    splits_mean : bool
        Whether the likelihood of repeated trials factorises into their mean's and
        their deviations' (Gaussian noise): else it is each trial's, summed.
    takes_missing : bool
        Whether :meth:`log_likelihood` takes samples not observed.
    from_repeats : bool
        Whether the noise is learnt from repeats before the model (the AR family,
        :func:`pmabayes.inference.noise.group_noise`); else its parameters are
        sampled with the model's.
    description : str
        The model in a sentence, for the fit file's ``noise.model``.
    label : str
        The model in words, for progress lines and reports (a class attribute where it
        is fixed; by default the name).
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    splits_mean: ClassVar[bool] = True
    takes_missing: ClassVar[bool] = True
    from_repeats: ClassVar[bool] = False

    @property
    def label(self) -> str:
        """The model in words, for progress lines and reports."""
        return self.name

    @abstractmethod
    def parameters(self, likelihood: Likelihood) -> tuple[Parameter, ...]:
        """The noise parameters with their priors for an experiment's likelihood.

        Parameters
        ----------
        likelihood : Likelihood
            Its data set may set the priors' scale (a force-input rig's) and bounds.

        Returns
        -------
        tuple of Parameter
        """

    @abstractmethod
    def log_likelihood(self, y: np.ndarray, x: np.ndarray, scale: float, noise: tuple,
                       observed: np.ndarray | None = None) -> np.ndarray:
        """Log density of the residual series, ``(batch, series)``.

        Parameters
        ----------
        y : numpy.ndarray
            ``(series, n)`` data (any value where not observed).
        x : numpy.ndarray
            ``(batch or 1, 1 or series, n)`` model positions.
        scale : float
            The residual's factor (``sqrt(R)`` for a mean of ``R`` trials).
        noise : tuple of numpy.ndarray
            The noise parameters, each ``(batch,)``.
        observed : numpy.ndarray, optional
            ``(1 or series, n)``, True where a sample enters; all of them by default.

        Returns
        -------
        numpy.ndarray
        """

    @abstractmethod
    def whiten(self, v: np.ndarray, scale: float, noise: tuple,
               seen: np.ndarray | None = None) -> np.ndarray:
        """Standardised innovations of ``scale * v`` (one series ``(n,)``): independent
        N(0, 1) when the noise model holds; NaN at samples not ``seen``.

        Parameters
        ----------
        v : numpy.ndarray
        scale : float
        noise : tuple of float
        seen : numpy.ndarray, optional

        Returns
        -------
        numpy.ndarray
        """

    @abstractmethod
    def draw(self, n_series: int, n_samples: int, noise: tuple,
             rng: np.random.Generator) -> np.ndarray:
        """Draw noise series ``(n_series, n_samples)``.

        Parameters
        ----------
        n_series, n_samples : int
        noise : tuple
            The noise parameters, scalars or one per series.
        rng : numpy.random.Generator

        Returns
        -------
        numpy.ndarray
        """

    def to_dict(self) -> dict:
        """JSON-ready record for the fit file (``noise_model``, the registry's name);
        :meth:`from_dict` rebuilds the model from it."""
        return {"noise_model": self.name}

    @classmethod
    def from_dict(cls, record: dict) -> NoiseModel:
        """Rebuild from :meth:`to_dict`'s record.

        Parameters
        ----------
        record : dict

        Returns
        -------
        NoiseModel
        """
        return cls()

    @staticmethod
    def broadcast(noise: tuple, batch: int) -> tuple[np.ndarray, ...]:
        """Each noise parameter as a contiguous ``(batch,)`` float array."""
        return tuple(np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=float), (batch,)))
                     for v in noise)

    def start(self, residual: np.ndarray, observed: np.ndarray | None,
              likelihood: Likelihood) -> tuple[np.ndarray, np.ndarray]:
        """A start for the search of a sampled noise, in unconstrained coordinates, and
        a shift to a second start (the better optimum of the two is kept).

        Parameters
        ----------
        residual : numpy.ndarray
            ``(n,)``, data minus model at the search's optimum (0 where not observed).
        observed : numpy.ndarray or None
            ``(1, n)`` mask of the samples seen.
        likelihood : Likelihood

        Returns
        -------
        start, shift : numpy.ndarray
            Both ``(len(parameters),)``.
        """
        raise NotImplementedError(f"noise model {self.name!r} learns its noise from repeats: "
                                  "it has no start of a sampled noise")

    def clip_start(self, z: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """The noise's columns of a search's start, moved inside their support where
        finite differences need room (``upper``: the parameters' upper bounds)."""
        return z


_REGISTRY: dict[str, type[NoiseModel]] = {}


def register_noise_model(cls: type[NoiseModel]) -> type[NoiseModel]:
    """Register a noise model under its ``name`` (a class decorator).

    Parameters
    ----------
    cls : type
        A subclass of :class:`NoiseModel` with a ``name`` of its own.

    Returns
    -------
    type
        ``cls``.

    Raises
    ------
    ValueError
        For a missing name or one already taken by another class.
    """
    if not (isinstance(cls, type) and issubclass(cls, NoiseModel)) or not cls.name:
        raise ValueError(f"a noise model is a NoiseModel subclass with a name, got {cls!r}")
    if _REGISTRY.get(cls.name, cls) is not cls:
        raise ValueError(f"noise model {cls.name!r} is already registered "
                         f"({_REGISTRY[cls.name].__module__}); choose another name")
    _REGISTRY[cls.name] = cls
    return cls


def noise_model_class(name: str) -> type[NoiseModel]:
    """The registered noise model of a name.

    Parameters
    ----------
    name : str

    Returns
    -------
    type

    Raises
    ------
    KeyError
        Naming the registered ones.
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"no noise model {name!r}; registered: {', '.join(sorted(_REGISTRY))}"
                       ) from None


def registered_noise_models() -> tuple[str, ...]:
    """The registered noise models' names, in registration order."""
    return tuple(_REGISTRY)
