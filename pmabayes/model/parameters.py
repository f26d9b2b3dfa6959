"""Model parameters and their priors.

A :class:`Parameter` keeps together everything pmabayes knows about one physical
quantity: its name, SI unit, a default value, a weakly informative prior, its
physical domain (a sign, a correlation's range; the prior must lie within it and
owns the support), the value at which an optional effect vanishes, and a one-line
physical meaning.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from statistics import NormalDist

import numpy as np

__all__ = ["Prior", "Uniform", "Normal", "LogNormal", "HalfNormal", "Parameter", "parse_prior",
           "OUTSIDE_DOMAIN_MAX"]


_STD = NormalDist()


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

    def cdf(self, value: float) -> float:
        """The probability below ``value``."""
        raise NotImplementedError

    def quantile(self, q: float) -> float:
        """The value below which the prior puts probability ``q`` (``0 < q < 1``)."""
        raise NotImplementedError


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

    def cdf(self, value):
        return min(max((value - self.low) / (self.high - self.low), 0.0), 1.0)

    def quantile(self, q):
        return self.low + q * (self.high - self.low)

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

    def cdf(self, value):
        return _STD.cdf((value - self.mu) / self.sigma)

    def quantile(self, q):
        return self.mu + self.sigma * _STD.inv_cdf(q)

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

    def cdf(self, value):
        if value <= 0:
            return 0.0
        return _STD.cdf((math.log(value) - math.log(self.median)) / self.sigma)

    def quantile(self, q):
        return self.median * math.exp(self.sigma * _STD.inv_cdf(q))

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

    def cdf(self, value):
        return 0.0 if value <= 0 else 2.0 * _STD.cdf(value / self.sigma) - 1.0

    def quantile(self, q):
        return self.sigma * _STD.inv_cdf(0.5 + 0.5 * q)

    def __str__(self) -> str:
        return f"HalfNormal({self.sigma:.12g})"


#: The most prior probability that may lie outside a parameter's physical domain: a
#: prior that puts more there is refused (:meth:`Parameter.check_prior`), never cut.
OUTSIDE_DOMAIN_MAX = 1e-9


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
        Default prior; users override it per model. The prior owns the support:
        no bound of the parameter narrows it.
    bounds : tuple of float
        The physical domain ``(lower, upper)``, e.g. ``(0, inf)`` for a stiffness or
        ``(-1, 1)`` for a correlation; unbounded by default. A prior that puts
        more than :data:`OUTSIDE_DOMAIN_MAX` of its probability outside it is
        refused (:meth:`check_prior`), never silently cut.
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
    per_experiment : bool
        True for a property of one recording rather than of the physics (a sensor's
        zero): in a fit of several experiments each has its own value, identified
        as ``NAME__EXPERIMENT``.
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
    per_experiment: bool = False

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"parameter name {self.name!r} must be a Python identifier")
        lo, hi = self.bounds
        if not lo < hi:
            raise ValueError(f"parameter {self.name!r}: bounds {self.bounds} need lower < upper")
        if not lo <= self.default <= hi:
            raise ValueError(
                f"parameter {self.name!r}: default {self.default} lies outside its bounds "
                f"(physical domain) {self.bounds}"
            )

    def in_bounds(self, value: np.ndarray | float) -> np.ndarray:
        """Whether ``value`` lies within the physical domain (elementwise)."""
        value = np.asarray(value, dtype=float)
        return (value >= self.bounds[0]) & (value <= self.bounds[1])

    def check_prior(self, prior: Prior | None = None) -> None:
        """Refuse a prior that leaves the parameter's physical domain.

        Parameters
        ----------
        prior : Prior, optional
            The prior to check; the parameter's own by default.

        Raises
        ------
        ValueError
            If more than :data:`OUTSIDE_DOMAIN_MAX` of the prior's probability lies
            outside :attr:`bounds`; the message names the parameter and the fix.
        """
        prior = self.prior if prior is None else prior
        lo, hi = self.bounds
        try:
            outside = prior.cdf(lo) + (1.0 - prior.cdf(hi))
        except NotImplementedError:  # a user's Prior without a cdf: judged by its support
            s_lo, s_hi = prior.support()
            outside = 0.0 if lo <= s_lo and s_hi <= hi else 1.0
        if outside > OUTSIDE_DOMAIN_MAX:
            hint = (" (a positive quantity takes LogNormal(median, sigma) or HalfNormal(sigma))"
                    if lo == 0.0 and hi == math.inf else "")
            raise ValueError(
                f"prior {prior} of parameter {self.name!r} puts {outside:.3g} of its "
                f"probability outside the parameter's physical domain [{lo:g}, {hi:g}] "
                f"{self.unit}; choose a prior within it{hint}")

    def log_prior(self, value: np.ndarray | float, prior: Prior | None = None) -> np.ndarray:
        """Prior log density, ``-inf`` outside the physical domain.

        Parameters
        ----------
        value : array_like
            Values in the parameter's unit.
        prior : Prior, optional
            A prior to use instead of the parameter's own (a model's override).

        Returns
        -------
        numpy.ndarray
            The log density, ``-inf`` outside the domain (where an accepted prior
            has no mass).
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

    Examples
    --------
    >>> from pmabayes.model.parameters import parse_prior
    >>> prior = parse_prior("LogNormal(5e4, 2)")
    >>> prior
    LogNormal(median=50000.0, sigma=2.0)
    >>> print(prior)
    LogNormal(median=50000, sigma=2)
    >>> parse_prior(str(prior)) == prior
    True
    >>> print(parse_prior("uniform(low=0, high=1)"))
    Uniform(0, 1)
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
