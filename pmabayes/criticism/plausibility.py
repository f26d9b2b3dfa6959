"""Whether an estimate is physics or an artefact: each parameter's plausible range.

A score test's one-step estimate is not held to a parameter's bounds, and a refit that
has nothing to explain may run to one of them: a Bouc-Wen exponent of -2.65 or an
encoder offset of -71.9 m on a record of millimetres are not findings. A value is
*plausible* when it lies

* within the parameter's hard bounds (a refit's value *on* a bound other than the
  effect's null, within 1e-4 of the range's width, is not: the data pushed it as far as
  it was let go);
* within the central ``1 - PRIOR_TAIL`` of the prior the model gives it (4.9 standard
  deviations of a normal prior, a factor ``exp(4.9 sigma)`` of a log-normal one): the
  prior says where the physics of such a rig lies, and :data:`PRIOR_TAIL` is far out in
  it, so only a value the prior all but rules out is called implausible;
* for a length of the measurement stage (an encoder offset), also anywhere within
  twice the largest measured ``|position|``: the data's own scale bounds where the
  sensor's zero can be, whatever the prior;
* and between the effect's null (where it vanishes) and that range: an effect that all
  but vanishes is no artefact.

A user whose rig is not the prior's sets a prior for it (``--prior``), and the range
moves with it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import stats

from pmabayes.data import Dataset
from pmabayes.model.model import Model
from pmabayes.model.parameters import HalfNormal, LogNormal, Normal, Prior, Uniform

__all__ = ["PRIOR_TAIL", "prior_range", "plausible_range", "implausible"]

#: Prior probability left outside the plausible range (both tails together).
PRIOR_TAIL = 1e-6
#: A refit's value this close to a bound (relative to the plausible range's width) is on it.
_AT_BOUND = 1e-4


def prior_range(prior: Prior, tail: float = PRIOR_TAIL) -> tuple[float, float]:
    """The central ``1 - tail`` of a prior.

    Parameters
    ----------
    prior : Prior
        One of the package's priors; another kind gives its support.
    tail : float
        Probability left outside, both tails together.

    Returns
    -------
    tuple of float
        ``(low, high)``.
    """
    z = float(stats.norm.isf(tail / 2.0))
    if isinstance(prior, Uniform):
        return prior.low, prior.high
    if isinstance(prior, Normal):
        return prior.mu - z * prior.sigma, prior.mu + z * prior.sigma
    if isinstance(prior, LogNormal):
        return prior.median * math.exp(-z * prior.sigma), prior.median * math.exp(z * prior.sigma)
    if isinstance(prior, HalfNormal):
        return 0.0, z * prior.sigma
    return prior.support()


def _data_scale_m(datasets: Sequence[Dataset]) -> float:
    return max((float(np.nanmax(np.abs(ds.position_m))) for ds in datasets), default=0.0)


def plausible_range(model: Model, name: str, datasets: Sequence[Dataset] = ()
                    ) -> tuple[float, float]:
    """A parameter's plausible range (see the module's docstring).

    Parameters
    ----------
    model : Model
        The model (its prior of the parameter, which may be a user's).
    name : str
        The parameter.
    datasets : sequence of Dataset
        The data (their scale widens the range of a measurement-stage length).

    Returns
    -------
    tuple of float
        ``(low, high)``.
    """
    p = model.parameter(name)
    lo, hi = prior_range(model.priors.get(name, p.prior))
    stage = next((e.stage for e in model.effects if name in e.parameter_names()), None)
    if stage == "measurement" and p.unit == "m" and datasets:
        scale = 2.0 * _data_scale_m(datasets)
        lo, hi = min(lo, -scale), max(hi, scale)
    if p.null is not None:  # an effect that all but vanishes is no artefact
        lo, hi = min(lo, p.null), max(hi, p.null)
    return max(lo, p.bounds[0]), min(hi, p.bounds[1])


def _unit(value: float, unit: str) -> str:
    return f"{value:.4g} {unit}".rstrip() if unit not in ("", "1") else f"{value:.4g}"


def implausible(model: Model, values: Mapping[str, float], names: Sequence[str],
                datasets: Sequence[Dataset] = (), *, refit: bool = False) -> str | None:
    """Why some of an effect's estimates are not physics, or None when all are plausible.

    Parameters
    ----------
    model : Model
        A model holding the parameters.
    values : mapping
        Their estimates.
    names : sequence of str
        The parameters to judge (an effect's tested or refitted ones).
    datasets : sequence of Dataset
        The data (for the scale of a measurement-stage length).
    refit : bool
        The values are a refit's (bounded): a value on a bound other than the null is
        implausible too.

    Returns
    -------
    str or None
        ``"x_offset = -71.9 m lies outside its plausible range (-0.0098 to 0.0098 m)"``,
        with one clause per implausible parameter.
    """
    out = []
    for n in names:
        if n not in values:
            continue
        v, p = float(values[n]), model.parameter(n)
        lo, hi = plausible_range(model, n, datasets)
        where = f"{_unit(lo, '')} to {_unit(hi, p.unit)}"
        if not (math.isfinite(v) and lo <= v <= hi):
            out.append(f"{n} = {_unit(v, p.unit)} lies outside its plausible range ({where})")
        elif refit and any(math.isfinite(b) and b != p.null
                           and abs(v - b) <= _AT_BOUND * (hi - lo) for b in p.bounds):
            out.append(f"{n} = {_unit(v, p.unit)} ran to its bound (plausible range {where})")
    return "; ".join(out) or None
