"""Model parameters and their priors.

A :class:`Parameter` keeps together everything pmabayes knows about one physical
quantity: its name, SI unit, a default value, a weakly informative prior, hard
bounds that exclude nonsense, the value at which an optional effect vanishes, and a
one-line physical meaning.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Prior", "Uniform", "Normal", "LogNormal", "HalfNormal", "Parameter", "parse_prior"]


class Prior:
    """Base class of the (univariate) prior distributions.

    Subclasses implement :meth:`logpdf`, :meth:`sample` and :meth:`support`; all work
    elementwise on NumPy arrays.
    """

    def logpdf(self, value: np.ndarray | float) -> np.ndarray:
        """Log density (up to truncation) at ``value``; ``-inf`` outside the support."""
        raise NotImplementedError

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None):
        """Draw from the prior with the generator ``rng``."""
        raise NotImplementedError

    def support(self) -> tuple[float, float]:
        """The interval outside which the density is zero."""
        return (-math.inf, math.inf)


@dataclass(frozen=True)
class Uniform(Prior):
    """Uniform prior on ``[low, high]``.

    Parameters
    ----------
    low, high : float
        Interval ends, ``low < high``.
    """

    low: float
    high: float

    def __post_init__(self) -> None:
        if not self.low < self.high:
            raise ValueError(f"Uniform prior needs low < high, got {self.low}, {self.high}")

    def logpdf(self, value):
        value = np.asarray(value, dtype=float)
        inside = (value >= self.low) & (value <= self.high)
        return np.where(inside, -math.log(self.high - self.low), -np.inf)

    def sample(self, rng, size=None):
        return rng.uniform(self.low, self.high, size)

    def support(self):
        return (self.low, self.high)

    def __str__(self) -> str:
        return f"Uniform({self.low:.12g}, {self.high:.12g})"


@dataclass(frozen=True)
class Normal(Prior):
    """Normal prior.

    Parameters
    ----------
    mu : float
        Mean.
    sigma : float
        Standard deviation, > 0.
    """

    mu: float
    sigma: float

    def __post_init__(self) -> None:
        if not self.sigma > 0:
            raise ValueError(f"Normal prior needs sigma > 0, got {self.sigma}")

    def logpdf(self, value):
        u = (np.asarray(value, dtype=float) - self.mu) / self.sigma
        return -0.5 * u * u - math.log(self.sigma * math.sqrt(2 * math.pi))

    def sample(self, rng, size=None):
        return rng.normal(self.mu, self.sigma, size)

    def __str__(self) -> str:
        return f"Normal({self.mu:.12g}, {self.sigma:.12g})"


@dataclass(frozen=True)
class LogNormal(Prior):
    """Log-normal prior for positive scale parameters.

    Parameters
    ----------
    median : float
        Median, > 0 (``exp`` of the log-mean).
    sigma : float
        Standard deviation of the logarithm, > 0: ``sigma = 1`` puts 90% of the mass
        within a factor of 5.2 of the median.
    """

    median: float
    sigma: float

    def __post_init__(self) -> None:
        if not (self.median > 0 and self.sigma > 0):
            raise ValueError(f"LogNormal prior needs median > 0 and sigma > 0, got {self}")

    def logpdf(self, value):
        value = np.asarray(value, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            logv = np.log(np.where(value > 0, value, np.nan))
            u = (logv - math.log(self.median)) / self.sigma
            out = -0.5 * u * u - logv - math.log(self.sigma * math.sqrt(2 * math.pi))
        return np.where(value > 0, out, -np.inf)

    def sample(self, rng, size=None):
        return self.median * np.exp(self.sigma * rng.standard_normal(size))

    def support(self):
        return (0.0, math.inf)

    def __str__(self) -> str:
        return f"LogNormal(median={self.median:.12g}, sigma={self.sigma:.12g})"


@dataclass(frozen=True)
class HalfNormal(Prior):
    """Half-normal prior on ``[0, inf)``.

    Parameters
    ----------
    sigma : float
        Scale, > 0.
    """

    sigma: float

    def __post_init__(self) -> None:
        if not self.sigma > 0:
            raise ValueError(f"HalfNormal prior needs sigma > 0, got {self.sigma}")

    def logpdf(self, value):
        value = np.asarray(value, dtype=float)
        u = value / self.sigma
        out = -0.5 * u * u + math.log(math.sqrt(2 / math.pi) / self.sigma)
        return np.where(value >= 0, out, -np.inf)

    def sample(self, rng, size=None):
        return np.abs(rng.normal(0.0, self.sigma, size))

    def support(self):
        return (0.0, math.inf)

    def __str__(self) -> str:
        return f"HalfNormal({self.sigma:.12g})"


@dataclass(frozen=True)
class Parameter:
    """One named physical parameter of a model or an effect.

    Parameters
    ----------
    name : str
        Unique name across the whole composed model (a clash is an error).
    unit : str
        SI unit, e.g. ``"N/m"``.
    default : float
        Nominal value: the paper's estimate for the base model, a typical
        laboratory size for an effect.
    prior : Prior
        Default prior; users override it per model.
    bounds : tuple of float
        Hard bounds ``(lower, upper)`` that exclude unphysical values; the prior
        is truncated to them.
    description : str
        One-line physical meaning.
    null : float or None
        For an effect's parameter, the value at which the effect vanishes (used
        when testing whether the effect is present); None for base parameters.
    vary : bool
        False for settings that are fixed at ``default`` unless the user frees them
        (for example the smoothing velocity of the Coulomb friction).
    latex : str
        Symbol for reports and the paper, e.g. ``r"\alpha"``.
    """

    name: str
    unit: str
    default: float
    prior: Prior
    bounds: tuple[float, float] = (-math.inf, math.inf)
    description: str = ""
    null: float | None = None
    vary: bool = True
    latex: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"parameter name {self.name!r} must be a Python identifier")
        lo, hi = self.bounds
        if not lo < hi:
            raise ValueError(f"parameter {self.name!r}: bounds {self.bounds} need lower < upper")
        if not lo <= self.default <= hi:
            raise ValueError(
                f"parameter {self.name!r}: default {self.default} lies outside its bounds "
                f"{self.bounds}"
            )

    def in_bounds(self, value: np.ndarray | float) -> np.ndarray:
        """Whether ``value`` lies within the hard bounds (elementwise)."""
        value = np.asarray(value, dtype=float)
        return (value >= self.bounds[0]) & (value <= self.bounds[1])

    def log_prior(self, value: np.ndarray | float, prior: Prior | None = None) -> np.ndarray:
        """Prior log density truncated to the bounds (unnormalised truncation).

        Parameters
        ----------
        value : array_like
            Values in the parameter's unit.
        prior : Prior, optional
            A prior to use instead of the parameter's own (a model's override).

        Returns
        -------
        numpy.ndarray
            The log density, ``-inf`` outside the bounds.
        """
        prior = self.prior if prior is None else prior
        return np.where(self.in_bounds(value), prior.logpdf(value), -np.inf)


_PRIOR_SPEC = re.compile(r"^\s*([A-Za-z]+)\s*\((.*)\)\s*$")


def parse_prior(text: str) -> Prior:
    """A prior from its printed form, e.g. ``"LogNormal(5e4, 2)"`` or ``"Uniform(0, 1)"``.

    The inverse of ``str(prior)``: the distribution's name (any case) and its
    parameters in order or by name (``LogNormal(median=5e4, sigma=2)``).

    Parameters
    ----------
    text : str
        The specification.

    Returns
    -------
    Prior

    Raises
    ------
    ValueError
        If the name is unknown, an argument is not a number, or the distribution
        rejects the values; the message lists the forms accepted.
    """
    kinds = {cls.__name__.lower(): cls for cls in (Uniform, Normal, LogNormal, HalfNormal)}
    forms = "Uniform(low, high), Normal(mu, sigma), LogNormal(median, sigma), HalfNormal(sigma)"
    match = _PRIOR_SPEC.match(str(text))
    if not match or match.group(1).lower() not in kinds:
        raise ValueError(f"prior {text!r} is not understood; write one of {forms}")
    cls = kinds[match.group(1).lower()]
    names = [f.name for f in dataclasses.fields(cls)]
    args: dict[str, float] = {}
    parts = [a.strip() for a in match.group(2).split(",") if a.strip()]
    for i, part in enumerate(parts):
        key, _, value = part.rpartition("=")
        key = key.strip() or (names[i] if i < len(names) else "")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"prior {text!r}: {value.strip()!r} is not a number; write one "
                             f"of {forms}") from None
        if key not in names or key in args:
            raise ValueError(f"prior {text!r}: {cls.__name__} takes ({', '.join(names)}); "
                             f"write one of {forms}")
        args[key] = number
    if len(args) != len(names):
        raise ValueError(f"prior {text!r}: {cls.__name__} takes ({', '.join(names)})")
    return cls(**args)
