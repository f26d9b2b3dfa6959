"""The settings of a diagnosis, checked: :class:`DiagnoseSettings`."""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass

from pmabayes.criticism.adequacy import ENERGY_TOLERANCE
from pmabayes.criticism.signature import Signature
from pmabayes.inference.likelihood import LEVEL_ADEQUATE, check_noise_model_name
from pmabayes.model.effects import get_effect

__all__ = ["DiagnoseSettings"]


#: how a refit finds its MAP (:attr:`DiagnoseSettings.refit_search`)
REFIT_SEARCHES = ("nested", "global")


@dataclass(frozen=True)
class DiagnoseSettings:
    """How to diagnose: levels, thresholds, refits, draws and the noise model.

    Every value is checked when the settings are made, so that a wrong one fails
    before any fitting.

    Parameters
    ----------
    level : float
        Family-wise false-alarm level of the ranking, in (0, 1).
    level_adequate : float
        Level of the Ljung-Box test of adequacy, in (0, 1).
    energy_tolerance : float
        Adequacy also needs the whitened residual's mean square within
        ``1 + energy_tolerance`` of pure noise (positive). A tolerance, not a
        chi-squared test: with the noise parameters estimated from a few trials
        the energy of pure noise scatters by about 0.03 around 1 (measured),
        twice the chi-squared spread, so an exact test would reject correct
        models. 0.1 means a model error below about a third of the noise level.
    max_refits : int
        Significant candidates refitted at once (0 or more), in the score test's order;
        where none of them is named, the next ``max_refits`` are refitted (once): the
        score test is first order, and its strongest candidates are not always those
        that, refitted, predict best.
    min_explained : float
        Fraction of the excess residual, in [0, 1], that a refit (alone or with
        the next candidate) must remove for its effect to be named missing.
    ci_prob : float
        Probability of the intervals, in (0, 1).
    n_draws : int
        Laplace draws for the ELPD and the intervals (50 or more).
    substeps : int or "auto"
        Simulator substeps per sample (1 or more), or ``"auto"``: the fewest that
        pass the simulator's own accuracy check on these data
        (:func:`~pmabayes.inference.posterior.choose_substeps`), as ``fit`` does.
    candidates : tuple of str or None
        Effects to test (any iterable of registered names is taken); every
        registered effect not in the model when None.
    noise_model : str
        The likelihood's noise model where the noise comes from repeats, as in
        :func:`pmabayes.inference.sampler.fit`: ``"auto"`` (AR(1) + white unless
        the repeats reject it, then their AR(p)), ``"ar1"`` or ``"ar"``. It is what
        the MAP, the refits, their intervals and the ELPD use; the score tests and
        the discrepancy step whiten with AR(1) + white.
    discrepancy : bool
        Estimate the missing force from the data when the model is above the floor
        and no candidate accounts for it
        (:func:`pmabayes.criticism.discrepancy.estimate_discrepancy`).
    refit_search : str
        How each refit finds its MAP. ``"nested"`` (the default): one global search,
        and polishes from the diagnosed model's MAP, which the refit nests (the
        effect at its null, and at its default), the highest kept; with several
        experiments, each one's own MAP (for the agreement test) likewise, from its
        own under the model. ``"global"``: the fit's searches in full for each refit
        (two global searches, and two more per experiment for its own MAP).
    refit_searches : int
        Global searches of each refit's MAP on the nested path (1 or 2), each on its
        own stream, the highest kept (with several experiments, each one's own MAP
        likewise); two cost about twice the time. On real data a refit's optimum can
        move from one stream to the next (``analyses/refit_streams.py``), with one
        search or two.
    processes : int or None
        Local worker processes the refits run in, one candidate each (all cores by
        default; 1 runs them here). The numbers do not depend on it: each refit has
        its own random stream.
    leave_experiments_out : bool or None
        Before a candidate is named, leave each experiment out in turn, fit the model
        with and without it to the others and predict the one left out
        (:mod:`~pmabayes.criticism.transfer`): a candidate that predicts them worse is
        not named, as one that predicts left-out trials worse is not. The ELPD leaves
        out trials, or stretches of a record, so it cannot see an effect that fits each
        load it was given and none it was not. None (the default): where two or more
        experiments differ in a declared condition (a dead load, a moving mass).

    Raises
    ------
    ValueError
        On a value out of its range, naming it and the range.
    pmabayes.model.effects.EffectError
        On a candidate that is not a registered effect.
    """

    level: float = 0.05
    level_adequate: float = LEVEL_ADEQUATE
    energy_tolerance: float = ENERGY_TOLERANCE
    max_refits: int = 3
    min_explained: float = 0.9
    ci_prob: float = 0.9
    n_draws: int = 400
    substeps: int | str = "auto"
    candidates: tuple[str, ...] | None = None
    noise_model: str = "auto"
    discrepancy: bool = True
    refit_search: str = "nested"
    refit_searches: int = 1
    processes: int | None = None
    leave_experiments_out: bool | None = None

    def __post_init__(self) -> None:
        if self.candidates is not None and not isinstance(self.candidates, tuple):
            object.__setattr__(self, "candidates", _names(self.candidates))
        for name in ("level", "level_adequate", "ci_prob"):
            _check_range(name, getattr(self, name), 0.0, 1.0, "in (0, 1)", open_=True)
        _check_range("min_explained", self.min_explained, 0.0, 1.0, "in [0, 1]")
        _check_range("energy_tolerance", self.energy_tolerance, 0.0, math.inf, "positive",
                     open_=True)
        for name, least in (("max_refits", 0), ("n_draws", 50), ("substeps", 1),
                            ("processes", 1)):
            value = getattr(self, name)
            if (name == "substeps" and value == "auto") or (name == "processes"
                                                             and value is None):
                continue
            if isinstance(value, bool) or not isinstance(value, numbers.Real) \
                    or int(value) != value or value < least:
                raise ValueError(f"{name} must be a whole number, at least {least}; "
                                 f"got {value!r}")
        check_noise_model_name(self.noise_model)
        if self.refit_searches not in (1, 2) or isinstance(self.refit_searches, bool):
            raise ValueError(f"refit_searches must be 1 or 2, got {self.refit_searches!r}")
        if self.leave_experiments_out not in (None, True, False):
            raise ValueError("leave_experiments_out must be True, False or None (where "
                             "the experiments' declared conditions differ); got "
                             f"{self.leave_experiments_out!r}")
        if self.refit_search not in REFIT_SEARCHES:
            raise ValueError(f"refit_search must be one of {', '.join(REFIT_SEARCHES)}; "
                             f"got {self.refit_search!r}")
        for c in self.candidates or ():
            get_effect(c)  # unknown names fail here, before any fitting

    def is_adequate(self, signature: Signature) -> bool:
        """The adequacy rule with these settings' tolerance and level.

        Parameters
        ----------
        signature : Signature
            A residual's signature.

        Returns
        -------
        bool
        """
        return signature.is_adequate(self.energy_tolerance, self.level_adequate)

    def all_adequate(self, signatures: Sequence[Signature]) -> bool:
        """Whether the residual is adequate in every experiment.

        Parameters
        ----------
        signatures : sequence of Signature
            One per experiment.

        Returns
        -------
        bool
        """
        return all(self.is_adequate(sig) for sig in signatures)

    def to_dict(self) -> dict:
        """JSON-ready values, one key a field (``candidates`` a list or None).

        Returns
        -------
        dict
        """
        out = asdict(self)
        out["candidates"] = None if self.candidates is None else list(self.candidates)
        return out


def _names(candidates: Iterable[str]) -> tuple[str, ...]:
    if isinstance(candidates, str):
        raise ValueError(f"candidates must be a sequence of effect names, got the string "
                         f"{candidates!r}: split a comma-separated list first")
    return tuple(candidates)


def _check_range(name: str, value: float, low: float, high: float, words: str, *,
                 open_: bool = False) -> None:
    inside = low < value < high if open_ else low <= value <= high
    if not inside:  # NaN fails here too
        raise ValueError(f"{name} must be {words}, got {value!r}")
