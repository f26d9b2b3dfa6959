"""The posterior density: the log prior and log likelihood of a model's free parameters
(and of a sampled noise), in the unconstrained coordinates the MAP search and the
sampler explore: log for positive scale parameters and atanh for the noise
correlation, with the Jacobian in the density. The documentation's theory page on the
posterior says why.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import numpy as np

from pmabayes.inference.likelihood import NOISE_PARAMETERS, JointLikelihood, Likelihood, NoiseChoice
from pmabayes.inference.noise import NoiseEstimate, _log_sech2
from pmabayes.model.parameters import HalfNormal, LogNormal, Parameter, Prior

__all__ = ["Posterior"]


def _transform_kind(p: Parameter, prior: Prior) -> str:
    if p.name == "rho_noise":
        return "atanh"
    if isinstance(prior, LogNormal | HalfNormal):  # their support is (0, inf)
        return "log"
    return "identity"


def _identified(models: list, names: list[str]) -> list[dict[str, str]]:
    """Each experiment's free parameters mapped to the identified parameters' names.

    Shared by name, except a per-experiment parameter in a fit of several experiments
    (``NAME__EXPERIMENT``), and a name whose prior differs between experiments (a rig
    value each gives its own prior for): one parameter per prior, named after its
    first experiment (``NAME__EXPERIMENT``).
    """
    multi = len(models) > 1
    ident = [{n: (f"{n}__{names[e]}" if multi and m.parameter(n).per_experiment else n)
              for n in m.free_names} for e, m in enumerate(models)]
    groups: dict[str, dict[str, list[int]]] = {}
    for e, m in enumerate(models):
        for n, i in ident[e].items():
            groups.setdefault(i, {}).setdefault(str(m.priors[n]), []).append(e)
    for i, by_prior in groups.items():
        if len(by_prior) > 1:
            for members in by_prior.values():
                for e in members:
                    ident[e] = {n: (f"{i}__{names[members[0]]}" if v == i else v)
                                for n, v in ident[e].items()}
    return ident


class Posterior:
    """Log posterior of a model's free parameters, given the noise, over experiments.

    Parameters
    ----------
    likelihood : Likelihood or sequence of Likelihood
        One per experiment: its data, its model (on its rig) and the noise model.
        The experiments' models share their parameters.
    noise : NoiseEstimate, None, or sequence of them
        One per noise group (see ``noise_groups``): the estimate from repeats
        (:func:`pmabayes.inference.noise.estimate_noise`), at whose mode the likelihood is
        evaluated, or None for a group without repeats, whose noise parameters
        are then sampled with the model's (under the guard of
        :meth:`pmabayes.inference.likelihood.Likelihood.noise_parameters`).
    names : sequence of str, optional
        The experiments' names (``experiment_1``, ... by default).
    noise_groups : sequence of int, optional
        The noise group of each experiment: experiments of one group share their
        noise (``tie_noise``). Each its own by default.
    noise_choices : sequence of NoiseChoice, optional
        Per experiment, the noise model its likelihood uses and why
        (:func:`pmabayes.inference.likelihood.choose_noise_model`; the likelihoods already
        use it), for the fit file. AR(1) + white, untested, by default.

    Attributes
    ----------
    names : tuple of str
        Identified parameters: the model's free parameters, then the start of each
        experiment whose start is estimated (``x0_m``, ``v0_m_s``, ``z0_offset_n``;
        ``x0_m[NAME]``, ... with several experiments;
        :meth:`pmabayes.inference.likelihood.Likelihood.start_parameters`), then any
        sampled noise parameters (``sigma_noise_m``, ... for one group,
        ``sigma_noise_m[NAME]``, ... per experiment otherwise).
    n_model, n_start : int
        How many of them are the model's, and starts'.
    start_columns : dict
        Experiment index to the columns of its estimated start.
    likelihoods : list of Likelihood
        One per experiment.
    likelihood : Likelihood or JointLikelihood
        The one experiment's, or all of them seen as one (for the global search).
    """

    def __init__(self, likelihood, noise, *, names=None, noise_groups=None,
                 noise_choices=None) -> None:
        liks = [likelihood] if isinstance(likelihood, Likelihood) else list(likelihood)
        if not liks:
            raise ValueError("a posterior needs at least one experiment")
        self.likelihoods: list[Likelihood] = liks
        self.n_experiments = len(liks)
        self.experiment_names: list[str] = (list(names) if names is not None else
                                            [f"experiment_{i + 1}" for i in range(len(liks))])
        self.groups: list[int] = (list(noise_groups) if noise_groups is not None
                                  else list(range(len(liks))))
        n_groups = max(self.groups) + 1
        self.group_noise: list[NoiseEstimate | None] = (
            [noise] if noise is None or isinstance(noise, NoiseEstimate) else list(noise))
        if len(self.group_noise) != n_groups or len(self.groups) != len(liks):
            raise ValueError(f"{len(liks)} experiments in {n_groups} noise groups need one noise "
                             f"entry per group, got {len(self.group_noise)}")
        self.likelihood = (liks[0] if len(liks) == 1
                           else JointLikelihood(liks, self.experiment_names))
        self.noise_choices: list[NoiseChoice] = [
            c if c is not None else NoiseChoice(lik.noise.name, lik.ar_noise, math.nan,
                                                model=lik.noise)
            for c, lik in zip(noise_choices or [None] * len(liks), liks, strict=True)]
        self.noise = self.group_noise[0]
        self.model = liks[0].model
        #: how the simulator's substeps and any data-scaled priors were chosen (set by
        #: :func:`pmabayes.inference.posterior.build_posterior`, for the fit file)
        self.settings_record: dict = {}
        params: list[Parameter] = []
        priors: list[Prior] = []
        names_out: list[str] = []
        self.identified = _identified([lik.model for lik in liks], self.experiment_names)
        for lik, ident in zip(liks, self.identified, strict=True):
            for n in lik.model.free_names:
                if ident[n] not in names_out:
                    names_out.append(ident[n])
                    params.append(lik.model.parameter(n))
                    priors.append(lik.model.priors[n])
        self.n_model = len(names_out)
        self._layout(liks, names_out)
        # estimated starts: three columns per experiment that declares one
        self.start_columns: dict[int, list[int]] = {}
        for e, lik in enumerate(liks):
            if not lik.start_parameters():
                continue
            self.start_columns[e] = []
            for p in lik.start_parameters():
                self.start_columns[e].append(len(params))
                params.append(p)
                priors.append(p.prior)
                names_out.append(p.name if len(liks) == 1
                                 else f"{p.name}[{self.experiment_names[e]}]")
        self.n_start = len(params) - self.n_model
        # sampled noise: the columns of each group without repeats
        self._noise_cols: dict[int, list[int]] = {}
        for g in range(n_groups):
            if self.group_noise[g] is not None:
                continue
            members = [e for e, gg in enumerate(self.groups) if gg == g]
            # the strictest guard of the group's experiments
            guarded = min((liks[e].noise_parameters() for e in members),
                          key=lambda ps: ps[1].bounds[1])
            label = (None if n_groups == 1 else
                     "+".join(self.experiment_names[e] for e in members))
            self._noise_cols[g] = []
            for p in guarded:
                self._noise_cols[g].append(len(params))
                params.append(p)
                priors.append(p.prior)
                names_out.append(p.name if label is None else f"{p.name}[{label}]")
        self.parameters: tuple[Parameter, ...] = tuple(params)
        self.names: tuple[str, ...] = tuple(names_out)
        self.priors: tuple[Prior, ...] = tuple(priors)
        self.kinds = tuple(
            _transform_kind(p, pr) for p, pr in zip(self.parameters, self.priors, strict=True)
        )
        self.lower = np.array([p.bounds[0] for p in self.parameters])
        self.upper = np.array([p.bounds[1] for p in self.parameters])

    def _layout(self, liks: list[Likelihood], names: list[str]) -> None:
        """The full parameter array: the first experiment's model's, then a column for
        each parameter of another experiment's model that it does not share (its own
        offset, its own rig value); each other experiment's ``columns``
        (:class:`~pmabayes.inference.likelihood.Likelihood`)."""
        first = liks[0].model
        template = list(first.theta(first.defaults)[0])
        slot = {self.identified[0].get(n, ("fixed", n, first.defaults[n])): j
                for j, n in enumerate(first.parameter_names)}
        columns = []
        for lik, ident in zip(liks, self.identified, strict=True):
            cols = []
            for n in lik.model.parameter_names:
                key = ident.get(n, ("fixed", n, lik.model.defaults[n]))
                if key not in slot:
                    slot[key] = len(template)
                    template.append(lik.model.defaults[n])
                cols.append(slot[key])
            columns.append(cols)
        for lik, cols in zip(liks, columns, strict=True):
            lik.columns = None if cols == list(range(len(template))) else np.array(cols)
        self._template = np.array(template, dtype=float)
        self._free_cols = np.array([slot[n] for n in names], dtype=int)

    def members(self, group: int) -> list[int]:
        """The experiments of a noise group, by index."""
        return [e for e, g in enumerate(self.groups) if g == group]

    def noise_columns(self, group: int) -> list[int]:
        """The columns of a noise group's sampled noise parameters (none where its noise
        comes from repeats)."""
        return list(self._noise_cols.get(group, []))

    def noise_of(self, experiment: int, theta: np.ndarray | None = None) -> tuple:
        """The noise parameters of an experiment: ``(sigma, rho, white)`` for AR(1) +
        white, its noise model's (:meth:`noise_names`) for a sampled one.

        Parameters
        ----------
        experiment : int
            Its index.
        theta : numpy.ndarray, optional
            Identified values ``(batch, ndim)``; needed where the noise is sampled.

        Returns
        -------
        tuple
            Floats (noise from repeats, at its mode) or ``(batch,)`` arrays.
        """
        g = self.groups[experiment]
        est = self.group_noise[g]
        if est is not None:
            return est.sigma, est.rho, est.white
        if theta is None:
            raise ValueError(f"the noise of experiment {self.experiment_names[experiment]} is "
                             "sampled with the model: give theta")
        theta = np.atleast_2d(theta)
        return tuple(theta[:, c] for c in self._noise_cols[g])

    def set_group_noise(self, group: int, estimate: NoiseEstimate,
                        choice: NoiseChoice) -> None:
        """Replace a noise group's estimate from repeats and its experiments' noise model.

        The group's likelihoods must already use ``choice`` (``use_noise``); used
        when the periods of a record from rest are referred to the model
        (:func:`pmabayes.inference.search.find_map`).
        """
        if self.group_noise[group] is None:
            raise ValueError(f"noise group {group} is sampled with the model, not estimated "
                             "from repeats")
        self.group_noise[group] = estimate
        for e, g in enumerate(self.groups):
            if g == group:
                self.noise_choices[e] = choice
        self.noise = self.group_noise[0]

    def noise_sampled(self, experiment: int) -> bool:
        """Whether an experiment's noise is sampled with the model (no repeats)."""
        return self.group_noise[self.groups[experiment]] is None

    def noise_values(self, theta: np.ndarray) -> dict:
        """The noise at one point ``(ndim,)``, for the MAP's record.

        Returns
        -------
        dict
            Each noise parameter (:meth:`noise_names`: ``sigma_noise_m``,
            ``rho_noise`` and ``sigma_white_m`` for AR(1) + white): floats for one
            experiment, ``{experiment name: value}`` for several.
        """
        theta = np.asarray(theta, dtype=float).reshape(1, -1)
        per = [[float(np.asarray(v).reshape(-1)[0]) for v in self.noise_of(e, theta)]
               for e in range(self.n_experiments)]
        keys = self.noise_names()
        if self.n_experiments == 1:
            return dict(zip(keys, per[0], strict=True))
        return {k: {n: per[e][j] for e, n in enumerate(self.experiment_names)}
                for j, k in enumerate(keys)}

    def noise_names(self) -> list[str]:
        """The noise parameters' names (:meth:`noise_of`'s order): the sampled noise
        model's, else AR(1) + white's (:data:`~pmabayes.inference.noise.NOISE_PARAMETERS`),
        which the repeats give. The experiments of one fit share one noise model."""
        for e in range(self.n_experiments):
            if self.noise_sampled(e):
                return [p.name for p in self.likelihoods[e].noise_parameters()]
        return [p.name for p in NOISE_PARAMETERS]

    @property
    def ndim(self) -> int:
        """Number of identified parameters."""
        return len(self.names)

    @property
    def n_searched(self) -> int:
        """The first columns, which the global search's cost depends on: the model's
        and the estimated starts' (not the sampled noise's)."""
        return self.n_model + self.n_start

    def start_of(self, experiment: int, theta: np.ndarray) -> np.ndarray | None:
        """An experiment's estimated start ``(batch, 3)`` in identified values, or None."""
        cols = self.start_columns.get(experiment)
        return None if cols is None else np.atleast_2d(theta)[:, cols]

    def alone(self, experiment: int) -> Posterior:
        """One experiment's posterior: its data alone, under this one's noise for it.

        Its likelihood is a copy, so that this posterior's keeps its columns.

        Parameters
        ----------
        experiment : int
            The experiment's index.

        Returns
        -------
        Posterior
        """
        return self.subset([experiment])[0]

    def subset(self, keep: Sequence[int]) -> tuple[Posterior, np.ndarray]:
        """Some experiments' posterior: their data alone, under this one's noise for them.

        Their likelihoods are copies, so that this posterior's keep their columns. A
        parameter may be named otherwise there (one experiment's own offset has no
        suffix alone; a rig value is named after its first experiment kept): the
        returned columns say where each of its parameters is here.

        Parameters
        ----------
        keep : sequence of int
            The experiments kept, by index, in their order.

        Returns
        -------
        posterior : Posterior
            The experiments' posterior.
        columns : numpy.ndarray
            For each of its parameters (its :attr:`names`), the column of the same
            parameter here.
        """
        keep = [int(e) for e in keep]
        groups = sorted({self.groups[e] for e in keep})
        sub = Posterior([copy.copy(self.likelihoods[e]) for e in keep],
                        [self.group_noise[g] for g in groups],
                        names=[self.experiment_names[e] for e in keep],
                        noise_groups=[groups.index(self.groups[e]) for e in keep],
                        noise_choices=[self.noise_choices[e] for e in keep])
        columns = np.full(sub.ndim, -1, dtype=int)
        for j, e in enumerate(keep):
            for n in sub.likelihoods[j].model.free_names:
                columns[sub.names.index(sub.identified[j][n])] = self.names.index(
                    self.identified[e][n])
            for mine, theirs in zip(sub.start_columns.get(j, []),
                                    self.start_columns.get(e, []), strict=True):
                columns[mine] = theirs
        for mine, theirs in enumerate(groups):
            for a, b in zip(sub.noise_columns(mine), self.noise_columns(theirs), strict=True):
                columns[a] = b
        return sub, columns

    def experiment_point(self, experiment: int, values: dict
                         ) -> tuple[dict, np.ndarray | None]:
        """An experiment's model parameters and estimated start at a point given by name.

        Parameters
        ----------
        experiment : int
            Its index.
        values : dict
            Values of the identified parameters by their names (:attr:`names`; a MAP's
            ``values``).

        Returns
        -------
        own : dict
            The experiment's model's free parameters under the model's names (its own
            offset, its rig value's, as ``identified`` maps them).
        start : numpy.ndarray or None
            Its estimated start ``(3,)``, None where the start is declared.
        """
        ident = self.identified[experiment]
        own = {n: float(values[ident[n]])
               for n in self.likelihoods[experiment].model.free_names}
        cols = self.start_columns.get(experiment)
        start = None if cols is None else np.array([float(values[self.names[c]])
                                                    for c in cols])
        return own, start

    def simulate(self, theta: np.ndarray, experiment: int) -> np.ndarray:
        """One experiment's model output ``(batch, n_outputs)`` for identified values
        ``(batch, ndim)`` (the model's parameters and the experiment's start)."""
        theta = np.atleast_2d(theta)
        start = self.start_of(experiment, theta)
        lik = self.likelihoods[experiment]
        full = self.full_theta(theta)
        return lik.simulate(full) if start is None else lik.simulate(full, start)

    def output(self, theta: np.ndarray) -> np.ndarray:
        """Every experiment's model output, concatenated as :attr:`likelihood` has them."""
        xs = [self.simulate(theta, e) for e in range(self.n_experiments)]
        return xs[0] if len(xs) == 1 else np.concatenate(xs, axis=1)

    # -- coordinates ------------------------------------------------------------
    def to_natural(self, z: np.ndarray) -> np.ndarray:
        """Natural parameter values from unconstrained coordinates ``(batch, ndim)``."""
        return self._map(z, 0)

    def to_unconstrained(self, theta: np.ndarray) -> np.ndarray:
        """Unconstrained coordinates from natural values ``(batch, ndim)``."""
        return self._map(theta, 1)

    #: each transform's (to natural, to unconstrained) maps
    _MAPS = {"log": (np.exp, np.log), "atanh": (np.tanh, np.arctanh)}

    def _map(self, values: np.ndarray, direction: int) -> np.ndarray:
        values = np.atleast_2d(np.asarray(values, dtype=float))
        out = values.copy()
        with np.errstate(over="ignore", divide="ignore"):
            for j, kind in enumerate(self.kinds):
                if kind in self._MAPS:
                    out[:, j] = self._MAPS[kind][direction](values[:, j])
        return out

    def log_jacobian(self, z: np.ndarray) -> np.ndarray:
        """``log |d theta / d z|`` per batch member."""
        z = np.atleast_2d(z)
        total = np.zeros(z.shape[0])
        for j, kind in enumerate(self.kinds):
            if kind == "log":
                total += z[:, j]
            elif kind == "atanh":
                total += _log_sech2(z[:, j])
        return total

    def full_theta(self, theta: np.ndarray) -> np.ndarray:
        """The full parameter array for identified values ``(batch, ndim)``.

        The model's, for one experiment or experiments that share every parameter;
        otherwise the first experiment's model's followed by the columns of the
        others' own parameters, of which each :class:`Likelihood` takes its own
        (``columns`` (:class:`~pmabayes.inference.likelihood.Likelihood`)).
        """
        theta = np.atleast_2d(theta)
        full = np.repeat(self._template[None, :], theta.shape[0], axis=0)
        full[:, self._free_cols] = theta[:, : self.n_model]
        return full

    # -- densities ----------------------------------------------------------------
    def log_prior(self, theta: np.ndarray, *, known: dict[int, np.ndarray] | None = None
                  ) -> np.ndarray:
        """Log prior density in natural coordinates, ``-inf`` outside the bounds.

        The one joint log prior of pmabayes: the sum of each parameter's
        :meth:`~pmabayes.model.parameters.Parameter.log_prior` under the model's priors.

        Parameters
        ----------
        theta : numpy.ndarray
            ``(batch, ndim)`` natural values.
        known : dict of int to numpy.ndarray, optional
            Terms already evaluated (:meth:`prior_terms`) for the columns where every
            row of a one-row ``theta`` has the values they were evaluated at: a search
            over a few columns (the noise's own) then evaluates only theirs, with the
            same numbers in the same order.
        """
        theta = np.atleast_2d(theta)
        known = known or {}
        total = np.zeros(theta.shape[0])
        with np.errstate(all="ignore"):  # densities are evaluated out of bounds too
            for j, (p, prior) in enumerate(zip(self.parameters, self.priors, strict=True)):
                term = known.get(j)
                total = total + (p.log_prior(theta[:, j], prior) if term is None else term)
        return total

    def prior_terms(self, theta: np.ndarray, columns) -> dict[int, np.ndarray]:
        """Each of ``columns``' term of :meth:`log_prior` at one row ``theta`` (``(1,
        ndim)``), as :meth:`log_prior`'s ``known``."""
        theta = np.atleast_2d(theta)
        with np.errstate(all="ignore"):
            return {int(j): self.parameters[j].log_prior(theta[:, j], self.priors[j])
                    for j in columns}

    def evaluate(
        self, theta: np.ndarray, *, return_x: bool = True,
        outputs: list[np.ndarray] | None = None, experiments: list[int] | None = None,
        prior_terms: dict[int, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Log prior, log likelihood and model output for natural values.

        Parameters
        ----------
        theta : numpy.ndarray
            ``(batch, ndim)`` natural values.
        return_x : bool
            Whether to return the model output (the sampler does not need it).
        outputs : list of numpy.ndarray, optional
            Each experiment's model output ``(1, n_outputs)``, where every member shares
            the model's parameters and start and only the sampled noise differs (the
            noise's own search): used instead of simulating each member again, with the
            same numbers.
        experiments : list of int, optional
            Only these experiments' likelihoods (all by default): where only their
            noise varies, the others' are a constant (the noise's own search, group by
            group). Needs ``return_x`` false.
        prior_terms : dict of int to numpy.ndarray, optional
            :meth:`log_prior`'s ``known``.

        Returns
        -------
        log_prior, log_likelihood : numpy.ndarray
            ``(batch,)``; ``-inf`` where out of bounds or the simulation failed. The
            likelihood is the sum over experiments of that of the trial mean given
            the experiment's noise (the deviations' part does not depend on the
            model); for a sampled noise, the record's whole likelihood.
        x : numpy.ndarray or None
            Model positions of the valid members (NaN rows elsewhere; several
            experiments' outputs concatenated along time), or None if no member was
            valid or ``return_x`` is false.
        """
        if experiments is not None and return_x:
            raise ValueError("the output of some experiments only is not returned")
        theta = np.atleast_2d(theta)
        lp = self.log_prior(theta, known=prior_terms)
        ll = np.full(theta.shape[0], -np.inf)
        ok = np.isfinite(lp)
        if not ok.any():
            return lp, ll, None
        sub = theta[ok]
        chosen = range(self.n_experiments) if experiments is None else experiments
        xs = ([self.simulate(sub, e) for e in chosen] if outputs is None
              else [np.broadcast_to(outputs[e], (sub.shape[0], outputs[e].shape[-1]))
                    for e in chosen])
        total = np.zeros(sub.shape[0])
        for e, x in zip(chosen, xs, strict=True):
            total += self.likelihoods[e].mean_log_likelihood(x, *self.noise_of(e, sub))
        # a failed simulation (non-finite output) has a non-finite likelihood: each
        # member's filter is its own arithmetic, so the others are unchanged
        ll[ok] = np.where(np.isfinite(total), total, -np.inf)
        if not return_x:
            return lp, ll, None
        x = np.full((theta.shape[0], self.likelihood.n_outputs), np.nan)
        x[ok] = np.concatenate(xs, axis=1)
        return lp, ll, x

    def log_prob_z(self, z: np.ndarray, outputs: list[np.ndarray] | None = None,
                   experiments: list[int] | None = None,
                   prior_terms: dict[int, np.ndarray] | None = None) -> np.ndarray:
        """Log posterior density in unconstrained coordinates (what emcee samples);
        ``outputs``, ``experiments`` and ``prior_terms`` as :meth:`evaluate`'s."""
        z = np.atleast_2d(z)
        theta = self.to_natural(z)
        lp, ll, _ = self.evaluate(theta, return_x=False, outputs=outputs,
                                  experiments=experiments, prior_terms=prior_terms)
        out = lp + ll + self.log_jacobian(z)
        return np.where(np.isfinite(out), out, -np.inf)

    def plausible_box(self, rng: np.random.Generator, names: tuple[str, ...]) -> np.ndarray:
        """Unconstrained ``(lower, upper)`` of the 0.5-99.5% prior range of ``names``."""
        idx = [self.names.index(n) for n in names]
        box = np.empty((len(idx), 2))
        for row, j in enumerate(idx):
            draws = self.priors[j].sample(rng, 20000)
            lo, hi = np.quantile(draws, [0.005, 0.995])
            if np.isfinite(self.lower[j]):  # a physical domain, e.g. a positive value
                lo = max(lo, self.lower[j] + 1e-12 * max(1.0, abs(self.lower[j])))
            hi = min(hi, self.upper[j])
            ends = np.ones((2, self.ndim))
            ends[:, j] = lo, hi
            box[row] = self.to_unconstrained(ends)[:, j]
        return box
