"""Bayesian identification, :func:`fit`: the posterior built
(:func:`pmabayes.inference.posterior.build_posterior`), its MAP
(:func:`pmabayes.inference.search.find_map`), then emcee ensembles started from the
Laplace approximation there, run in parallel processes with resumable HDF5 chains
until they converge, and the fit file (:mod:`pmabayes.inference.fitfile`).

Convergence is judged after every round of steps: the kept chain at least
``tau_multiple`` integrated autocorrelation times long, the ESS of every parameter at
least ``min_ess``, and R-hat across independent ensembles below ``max_rhat``. R-hat
over emcee's walkers, which the moves couple, is reported as indicative only. The
documentation's identification guide gives the details.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import arviz as az
import emcee
import numpy as np
import xarray as xr

from pmabayes.data import Dataset
from pmabayes.inference.density import Posterior
from pmabayes.inference.disturbance import settle_disturbance, with_disturbance
from pmabayes.inference.errors import (
    ConvergenceWarning,
    DisagreementWarning,
    FitError,
    PoorFitWarning,
)
from pmabayes.inference.fitfile import fit_tree, set_fit_info
from pmabayes.inference.likelihood import check_noise_model_name
from pmabayes.inference.noise_start import refer_periods
from pmabayes.inference.posterior import build_posterior
from pmabayes.inference.search import MapResult, disagreement_text, find_map
from pmabayes.inference.trials import check_trials, keep_trials
from pmabayes.model.model import Model
from pmabayes.parallel import Runner
from pmabayes.util import Progress, fingerprint, local_cores, show_progress, side_stream

__all__ = ["FitSettings", "fit"]


@dataclass(frozen=True)
class FitSettings:
    """How to sample.

    Parameters
    ----------
    n_walkers : int
        Walkers per ensemble, at least twice the number of parameters: the
        default, 24, allows 12 (the base model with every built-in effect, or
        with three one-parameter effects on a single record, whose noise is
        sampled too); larger models need more. The run's length is set by
        ``tau_multiple``, not by ``min_ess``: on the bundled data 2 x 24 walkers
        reach an ESS of about 1,100 where 400 is asked, so more walkers than the
        parameters need cost time and buy ESS no one asked for.
    n_ensembles : int
        Independent ensembles (R-hat across them needs two or more).
    max_steps : int
        Budget of steps per ensemble.
    max_seconds : float or None
        Budget of wall time for sampling.
    check_every : int
        Steps between convergence checks: a run stops at most this many steps
        after it has converged.
    tau_multiple : float
        Required kept chain length in integrated autocorrelation times, each
        estimated on the whole kept chain (the burn-in, three of them, dropped),
        averaged over the ensemble's walkers. At 20 the estimate of ``tau`` runs
        somewhat short (on the bundled data 14-16 steps at the 400 steps where the
        run stops, against 18-21 from 1,100 steps), and the ESS, about
        ``n_walkers * n_ensembles * 20`` (reported 1,100, at least 850 with the
        longer run's ``tau``), stays well above ``min_ess``; R-hat across the
        independent ensembles guards against a chain that has not mixed. The
        calibration study (README, Calibration) checks the intervals at this
        setting.
    min_ess : float
        Required effective sample size of every parameter.
    max_rhat : float
        Required R-hat across ensembles (when there are several).
    processes : int or None
        Parallel processes for the ensembles (default: one per ensemble, at most
        the number of cores).
    ppc_draws : int
        Posterior draws stored in the posterior predictive.
    moves : str
        ``"de"`` (differential-evolution moves, 80% DEMove and 20% DESnookerMove;
        shorter autocorrelation times on these near-Gaussian posteriors) or
        ``"stretch"`` (emcee's default).
    progress : bool
        Print progress to stderr, every stage's (:func:`pmabayes.util.show_progress`).
    substeps : int or "auto"
        Simulator substeps per sample interval (more for a lightly damped
        oscillator near the sample rate). ``"auto"`` (the default) chooses them
        from the simulator's accuracy check at the prior's median
        (:func:`pmabayes.inference.posterior.choose_substeps`); the fit file records
        the choice (``substeps`` and ``substeps_choice``).
    tie_noise : bool
        One noise for all experiments (same sensor, same disturbance) instead of
        one per experiment.
    tie_segments : bool
        The segments of one record (:func:`pmabayes.data.load_segments`) share one
        noise (the default), as one sensor's; False gives each its own.
    noise_model : {"auto", "ar1", "ar", "student_t"} or a registered noise model's name
        The noise model of the likelihood (:mod:`pmabayes.inference.noise`;
        :func:`pmabayes.inference.noise.choose_noise_model`). Where the noise comes
        from repeats: ``"auto"`` keeps AR(1) + white unless the repeats' deviations
        reject it (then their AR(p) model), ``"ar1"`` always keeps it, ``"ar"`` always
        uses the AR(p); records without repeats keep the sampled AR(1) + white under
        its guard. ``"student_t"``: Student-t white noise (heavy tails, for
        outliers), its parameters sampled with the model's. The fit file records
        each experiment's (``experiments[i]["noise_model"]``).
    steady_state_tol_m : float or None
        Tolerance of the periodic steady state of data that start in it; None takes
        each sidecar's ``steady_state_tol_m`` (or 1e-9 m).
    max_warmup_periods : int or None
        Most periods simulated to find that steady state; None takes each sidecar's
        ``max_warmup_periods`` (or 256).

    Raises
    ------
    FitError
        For a setting out of its range (the walkers' number is checked against the
        model's parameters by :func:`fit`).
    """

    n_walkers: int = 24
    n_ensembles: int = 2
    max_steps: int = 20000
    max_seconds: float | None = None
    check_every: int = 100
    tau_multiple: float = 20.0
    min_ess: float = 400.0
    max_rhat: float = 1.01
    processes: int | None = None
    ppc_draws: int = 40
    moves: str = "de"
    progress: bool = False
    substeps: int | str = "auto"
    tie_noise: bool = False
    noise_model: str = "auto"
    steady_state_tol_m: float | None = None
    max_warmup_periods: int | None = None
    tie_segments: bool = True

    def __post_init__(self) -> None:
        if self.max_steps < 20:
            raise FitError(f"max_steps must be at least 20 (the autocorrelation time needs a "
                           f"chain), got {self.max_steps}")
        if self.n_ensembles < 1:
            raise FitError(f"n_ensembles must be at least 1 (2 or more for R-hat across "
                           f"ensembles), got {self.n_ensembles}")
        if self.substeps != "auto" and not (isinstance(self.substeps, int | np.integer)
                                            and not isinstance(self.substeps, bool)
                                            and self.substeps >= 1):
            raise FitError(f"substeps must be a whole number >= 1 or 'auto', got "
                           f"{self.substeps!r}")
        if self.steady_state_tol_m is not None and not self.steady_state_tol_m > 0:
            raise FitError(f"steady_state_tol_m must be > 0 m, got {self.steady_state_tol_m!r}")
        if self.max_warmup_periods is not None and not (
                isinstance(self.max_warmup_periods, int | np.integer)
                and self.max_warmup_periods >= 3):
            raise FitError(f"max_warmup_periods must be a whole number >= 3, got "
                           f"{self.max_warmup_periods!r}")
        if self.moves not in ("de", "stretch"):
            raise FitError(f"unknown moves {self.moves!r}; use 'de' or 'stretch'")
        try:
            check_noise_model_name(self.noise_model)
        except ValueError as err:
            raise FitError(str(err)) from None


_WORKER_POSTERIOR: Posterior | None = None


def _init_worker(posterior: Posterior) -> None:
    global _WORKER_POSTERIOR
    _WORKER_POSTERIOR = posterior


def _moves(kind: str):
    if kind == "stretch":
        return None  # emcee's default StretchMove
    if kind == "de":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    raise FitError(f"unknown moves {kind!r}; use 'de' or 'stretch'")


def _advance(job: tuple) -> int:
    """Advance one ensemble by ``n_steps`` and append them to its HDF5 file.

    ``job`` is ``(path, n_steps, initial, seed, moves)``. The file has emcee's
    ``HDFBackend`` layout (readable with ``emcee.backends.HDFBackend(path,
    name="mcmc")``) and records the random state after every round, so a run
    resumed from it continues exactly as an uninterrupted one. Steps run in
    memory and are written once per round: emcee's backend reopens the file at
    every step, which costs more than a step. The round is written to a copy that
    replaces the file only when complete: a process killed mid-write leaves the
    last complete round behind, never half of one.
    """
    path, n_steps, initial, seed, moves = job
    posterior = _WORKER_POSTERIOR
    tmp = path + ".tmp"
    if os.path.exists(path):
        shutil.copyfile(path, tmp)
    elif os.path.exists(tmp):
        os.remove(tmp)  # the debris of a round that never completed
    store = emcee.backends.HDFBackend(tmp, name="mcmc")
    if store.initialized and store.iteration > 0:
        state = store.get_last_sample()
    else:
        # emcee has no seed argument: its RandomState comes from our seed
        state = emcee.State(initial, random_state=np.random.RandomState(seed).get_state())
        store.reset(initial.shape[0], posterior.ndim)
    if n_steps <= 0:  # already ahead (another ensemble's round was cut short)
        done = store.iteration  # read before the copy it reads from goes
        os.remove(tmp)
        return done
    sampler = emcee.EnsembleSampler(state.coords.shape[0], posterior.ndim,
                                    posterior.log_prob_z, vectorize=True, moves=_moves(moves))
    # the walkers are drawn from the Laplace approximation, full rank by construction;
    # emcee's moves are affine invariant, so a posterior that is narrow across a ridge
    # (a scale shared by stiffness, damping and a rig's area) does not hinder them, but
    # its condition-number check of the start would refuse such an ensemble
    final = sampler.run_mcmc(state, n_steps, progress=False, skip_initial_state_check=True)
    store.grow(n_steps, None)
    with store.open("a") as f:
        g = f[store.name]
        it = int(g.attrs["iteration"])
        g["chain"][it: it + n_steps] = sampler.get_chain()
        g["log_prob"][it: it + n_steps] = sampler.get_log_prob()
        g["accepted"][:] += sampler.backend.accepted
        for i, v in enumerate(final.random_state):
            g.attrs[f"random_state_{i}"] = v
        g.attrs["iteration"] = it + n_steps
    os.replace(tmp, path)  # the commit
    return it + n_steps


class _Chains:
    """A chains folder: the stamp ``fit.json`` (fingerprint and MAP) and one HDF5
    file per ensemble. The folder is made only when the MAP is there to stamp."""

    def __init__(self, folder: Path, n_ensembles: int, key: str) -> None:
        self.folder = folder
        self.key = key
        self.stamp = folder / "fit.json"
        self.paths = [str(folder / f"ensemble_{e}.h5") for e in range(n_ensembles)]

    def _files(self) -> list[str]:
        return [p + s for p in self.paths for s in ("", ".tmp")]

    def clear(self) -> None:
        """Discard the chains and the stamp (a restart)."""
        for p in [*self._files(), str(self.stamp)]:
            if os.path.exists(p):
                os.remove(p)

    def saved_map(self) -> tuple[MapResult, float] | None:
        """The stamped MAP and its time, or None for a fresh start."""
        if not self.stamp.exists():
            return None
        saved = json.loads(self.stamp.read_text())
        if saved.get("fingerprint") != self.key:
            raise FitError(
                f"{self.folder} holds chains of a different fit (other data, model, seed or "
                "sampler settings); pass restart=True (--restart) or choose another output"
            )
        return MapResult.from_record(saved["map"]), saved["timings_s"]["map"]

    def start(self, map_result: MapResult, t_map: float) -> None:
        """Stamp a fresh start (atomically), discarding chains of any earlier one."""
        self.folder.mkdir(parents=True, exist_ok=True)
        for p in self._files():
            if os.path.exists(p):
                os.remove(p)
        tmp = self.stamp.with_name(self.stamp.name + ".tmp")
        tmp.write_text(json.dumps({"fingerprint": self.key, "map": map_result.record(),
                                   "timings_s": {"map": t_map}}, indent=1))
        os.replace(tmp, self.stamp)

    def iterations(self) -> list[int]:
        """Completed steps of each ensemble."""
        return [emcee.backends.HDFBackend(p, name="mcmc", read_only=True).iteration
                if os.path.exists(p) else 0 for p in self.paths]

    def read(self) -> list[np.ndarray]:
        """Every ensemble's chain ``(steps, walkers, ndim)``."""
        return [emcee.backends.HDFBackend(p, name="mcmc", read_only=True).get_chain()
                for p in self.paths]

    def kept(self, diag: _Diagnostics) -> tuple[np.ndarray, np.ndarray]:
        """Kept draws ``(chain, draw, ndim)`` and their log density ``(chain, draw)``:
        burn-in dropped, thinned, a chain per walker, ensemble after ensemble."""
        zs, lps = [], []
        for p in self.paths:
            b = emcee.backends.HDFBackend(p, name="mcmc", read_only=True)
            zs.append(b.get_chain(discard=diag.burn, thin=diag.thin)[
                : (diag.n_steps - diag.burn) // diag.thin])
            lps.append(b.get_log_prob(discard=diag.burn, thin=diag.thin)[: zs[-1].shape[0]])
        n_draw = min(z.shape[0] for z in zs)
        z = np.concatenate([zz[:n_draw].transpose(1, 0, 2) for zz in zs])
        lp_z = np.concatenate([ll[:n_draw].T for ll in lps])
        return z, lp_z


@contextlib.contextmanager
def _chains_folder(chains_dir: str | Path | None) -> Iterator[Path]:
    """The folder for the chains: a temporary one when none is given. A failure
    before any chain is written leaves no folder this call made."""
    if chains_dir is None:
        with tempfile.TemporaryDirectory(prefix="pmabayes-chains-") as tmp:
            yield Path(tmp)
        return
    folder = Path(chains_dir)
    existed = folder.exists()
    try:
        yield folder
    except BaseException:
        if not existed and folder.is_dir() and not any(folder.glob("ensemble_*.h5")):
            shutil.rmtree(folder, ignore_errors=True)
        raise


@dataclass
class _Diagnostics:
    converged: bool
    messages: list
    burn: int
    thin: int
    tau: np.ndarray
    ess: np.ndarray
    rhat_ensembles: np.ndarray | None
    n_steps: int

    def record(self, settings: FitSettings, names, rhat: np.ndarray, resumed: bool) -> dict:
        """The ``convergence`` entry of a fit's metadata (undefined values as None)."""

        def named(values):
            return None if values is None else {
                n: (float(v) if np.isfinite(v) else None)
                for n, v in zip(names, values, strict=True)}

        return {"converged": self.converged, "messages": self.messages,
                "n_ensembles": settings.n_ensembles, "n_walkers": settings.n_walkers,
                "n_steps": self.n_steps, "burn": self.burn, "thin": self.thin,
                "tau": named(self.tau), "ess": named(self.ess), "rhat": named(rhat),
                "rhat_ensembles": named(self.rhat_ensembles),
                "min_ess": settings.min_ess, "tau_multiple": settings.tau_multiple,
                "resumed": resumed}


def _convergence(chains: list[np.ndarray], names, settings: FitSettings,
                 rhat_always: bool = True) -> _Diagnostics:
    """Convergence of ensembles' chains ``(steps, walkers, ndim)`` (unconstrained);
    without ``rhat_always``, R-hat across ensembles only where the other checks pass
    (a round's check: the stop is the same, the round's line may lack R-hat)."""
    n = min(c.shape[0] for c in chains)
    ndim = chains[0].shape[2]
    names = np.array(names)
    # tau from the second half (past any transient), per ensemble and parameter; NaN
    # where a walker has not moved there (nothing to estimate it from yet)
    with np.errstate(invalid="ignore", divide="ignore"):
        taus = np.array([
            emcee.autocorr.integrated_time(c[n // 2: n], tol=0, quiet=True) for c in chains
        ])
    tau = taus.max(axis=0)
    undefined = ~np.isfinite(tau)
    tau_max = float(tau[~undefined].max()) if not undefined.all() else float(n)
    burn = n // 2 if undefined.any() else min(int(math.ceil(3 * tau_max)), n // 2)
    kept = n - burn
    if burn < n // 2:
        # re-estimated on the whole kept chain: a short window underestimates tau
        with np.errstate(invalid="ignore", divide="ignore"):
            taus = np.array([emcee.autocorr.integrated_time(c[burn:n], tol=0, quiet=True)
                             for c in chains])
        tau = np.fmax(taus.max(axis=0), tau)
        undefined = ~np.isfinite(tau)
        tau_max = float(tau[~undefined].max()) if not undefined.all() else float(n)
    ess = np.sum([c.shape[1] * kept / t for c, t in zip(chains, taus, strict=True)], axis=0)
    kept_chains = [c[burn:n] for c in chains]
    messages = []
    if undefined.any():
        messages.append(
            f"the autocorrelation time of {', '.join(names[undefined])} cannot be estimated "
            f"yet (a walker has not moved in the last {n - n // 2} of {n} steps); the run is "
            "too short to judge"
        )
    short = kept < settings.tau_multiple * tau  # False where tau is undefined
    if short.any():
        messages.append(
            f"kept chain of {kept} steps is shorter than {settings.tau_multiple:g} "
            f"autocorrelation times for {', '.join(names[short])} "
            f"(tau up to {tau_max:.0f} steps)"
        )
    low = ess < settings.min_ess
    if low.any():
        messages.append(
            f"ESS below {settings.min_ess:g} for "
            + ", ".join(f"{nm} ({e:.0f})" for nm, e in zip(names[low], ess[low], strict=True))
        )
    # R-hat is defined across independent ensembles; emcee's walkers are coupled
    # by the moves, so their R-hat is reported as indicative only. Its rank
    # normalisation of every kept draw is the dearest check: in a round it is needed
    # only when the others pass (it cannot make a failing round pass)
    rhat_ens = None
    if len(chains) > 1 and (rhat_always or not messages):
        per_ens = np.stack([k.reshape(-1, ndim) for k in kept_chains])  # step-major
        rhat_ens = np.array([float(az.rhat(per_ens[:, :, j], method="rank"))
                             for j in range(ndim)])
    if rhat_ens is not None and (rhat_ens >= settings.max_rhat).any():
        bad = rhat_ens >= settings.max_rhat
        messages.append(
            f"R-hat across ensembles at or above {settings.max_rhat} for "
            + ", ".join(f"{nm} ({r:.4f})" for nm, r in zip(names[bad], rhat_ens[bad],
                                                           strict=True))
        )
    # stored draws: thinned by at least tau/2 and to about 8000 in all (convergence
    # and ESS are judged on the full chain; the store feeds summaries and LOO)
    n_chains = sum(c.shape[1] for c in chains)
    thin = max(1, int(tau_max // 2), math.ceil(kept * n_chains / 8000))
    return _Diagnostics(not messages, messages, burn, thin, tau, ess, rhat_ens, n)


def _walker_rhat(theta: np.ndarray) -> np.ndarray:
    """Rank-normalised split R-hat over walkers of stored draws ``(chain, draw, ndim)``
    in natural units: the value ArviZ computes from the fit file."""
    return np.array([float(az.rhat(theta[:, :, j], method="rank"))
                     for j in range(theta.shape[2])])


def _fingerprint(posterior: Posterior, settings: FitSettings, seed) -> str:
    """What makes chains resumable: the data, the models, the noise, the seed and the
    ensembles."""
    liks = posterior.likelihoods
    model = posterior.model
    extra = {"model": model.describe(), "rig": model.rig.to_dict(),
             "effects": model.effect_names, "seed": seed, "n_walkers": settings.n_walkers,
             "n_ensembles": settings.n_ensembles, "substeps": liks[0].substeps}
    if len(liks) > 1 or posterior.noise_sampled(0):
        # a fit of one experiment with repeats keeps the fingerprint it always had
        extra.update(rigs=[lik.model.rig.to_dict() for lik in liks],
                     names=posterior.experiment_names, groups=posterior.groups,
                     sampled_noise=list(posterior.names[posterior.n_model:]))
    records = [lik.noise.to_dict() for lik in liks]
    if any(records):
        # chains of an AR(1) + white likelihood are not those of another noise model's
        # (an AR(p)'s keeps the fingerprint it always had: its autocovariance)
        extra["noise_models"] = [r.get("autocovariance_m2", r or None) for r in records]
    if any(lik.observed is not None or lik.own_inputs or lik.start_parameters()
           for lik in liks):
        # what else the likelihood is of: samples missing in it, inputs, starts
        extra["likelihood"] = [[lik.observed is not None, lik.own_inputs,
                                [str(p.prior) for p in lik.start_parameters()]]
                               for lik in liks]
    arrays = [a for lik in liks for a in (lik.dataset.position_m,
                                          lik.dataset.input if lik.own_inputs else lik.input,
                                          *(() if lik.observed is None else (lik.observed,)))]
    return fingerprint(*arrays, extra)


def _round_line(diag: _Diagnostics, settings: FitSettings, seconds: float) -> str:
    """One progress line: a bar towards convergence (the run stops when the chain is
    long enough, not at a known step count) and where the run stands."""
    tau = diag.tau[np.isfinite(diag.tau)]
    tau_max = float(tau.max()) if tau.size else math.nan
    kept = diag.n_steps - diag.burn
    ess_min = float(np.nanmin(diag.ess)) if np.isfinite(diag.ess).any() else 0.0
    frac = min(1.0, kept / (settings.tau_multiple * tau_max), ess_min / settings.min_ess)
    bar = "#" * int(round(20 * frac)) if np.isfinite(frac) else ""
    needed = (f"{kept} of {settings.tau_multiple * tau_max:.0f} steps needed "
              f"({settings.tau_multiple:g} x tau {tau_max:.0f})" if tau.size == diag.tau.size
              else f"{kept} steps (tau cannot be estimated yet)")
    return (f"[{bar:-<20}] step {diag.n_steps} (budget {settings.max_steps}) x "
            f"{settings.n_ensembles} ensembles x {settings.n_walkers} walkers: kept "
            f"{needed}, ESS min {ess_min:.0f}"
            + (f", R-hat across ensembles max {diag.rhat_ensembles.max():.4f}"
               if diag.rhat_ensembles is not None else "")
            + f", {seconds:.0f} s")


def _sample_rounds(posterior: Posterior, chains: _Chains, initials: list[np.ndarray],
                   ens_seeds: list[int], settings: FitSettings, runner: Runner,
                   say: Progress) -> _Diagnostics:
    """Advance all ensembles round by round until converged or out of budget."""
    t_sample = time.perf_counter()
    diag = None
    while True:
        done = chains.iterations()
        n_done = min(done)
        budget_left = settings.max_steps - n_done
        if diag is not None and (diag.converged or budget_left <= 0):
            break
        elapsed = time.perf_counter() - t_sample
        if diag is not None and settings.max_seconds and elapsed > settings.max_seconds:
            break
        step = min(settings.check_every, budget_left) if budget_left > 0 else 0
        if step > 0:
            jobs = [(p, step - (d - n_done), initials[e] if d == 0 else None, ens_seeds[e],
                     settings.moves)
                    for e, (p, d) in enumerate(zip(chains.paths, done, strict=True))]
            for _ in runner.map(_advance, jobs):
                pass
        current = chains.read()
        if min(c.shape[0] for c in current) < 20:
            continue
        diag = _convergence(current, posterior.names, settings, rhat_always=False)
        say.say(_round_line(diag, settings, time.perf_counter() - t_sample))
        if step == 0:
            break
    return diag


def fit(
    datasets: Dataset | Sequence[Dataset],
    model: Model | None = None,
    *,
    seed: int | None = 0,
    settings: FitSettings | None = None,
    chains_dir: str | Path | None = None,
    restart: bool = False,
    trials: Sequence[int] | None = None,
) -> xr.DataTree:
    """Identify a model's parameters from one or more experiments: MAP, then posterior.

    Each data set is an experiment: its own input, length, rig (its metadata's
    ``rig``) and trials (one or more). The physical parameters are shared; the
    noise belongs to each experiment unless ``settings.tie_noise`` (the segments of one
    record share theirs unless ``settings.tie_segments`` is off). An experiment's noise is
    learnt from its repeats (trials, or the periods of a single periodic record);
    a record without repeats has it identified jointly with the model under a guard
    (see :mod:`pmabayes.inference.likelihood`). Samples not observed (gaps, a
    declared warm-up) are missing in the likelihood; trials with their own (measured)
    inputs are each simulated on theirs, their noise learnt from their residuals at
    the MAP; a start declared ``"estimate"`` is identified with the model (see the
    same module).

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        The experiments, all with the same kind of input (pressure or force).
    model : Model, optional
        The model (effects, priors, fixed values); by default the base model on the
        first experiment's rig (``Model.for_dataset``: its metadata's ``rig``, else the
        characterisation rig, said once per file). With one experiment it is used as
        given. With several, each experiment gets it
        on the rig its metadata records (``Model.for_dataset``), or on the
        model's rig where the metadata records none.
    seed : int or None
        Seed of everything random (global search, walkers, emcee, predictive
        noise). The same seed gives the same numbers, to the bit.
    settings : FitSettings, optional
        Sampler, simulator and noise-model settings.
    chains_dir : str or Path, optional
        Where the ensembles' HDF5 chains live. A run pointed at the chains of an
        interrupted run with the same data, model, seed and settings resumes them;
        without it a temporary folder is used. It is made once the MAP is found,
        and a failure before any chain is written removes it again.
    restart : bool
        Discard existing chains in ``chains_dir`` instead of resuming.
    trials : sequence of int, optional
        Fit only these trials (ids, as in the file's ``trial`` column) of the data,
        which must come from one file (a data set, or the segments of one record);
        the others are held out, e.g. for :func:`pmabayes.validate` with
        ``trials=``. The fit file records the trials fitted, per experiment
        (``experiments[i].trial_ids``). All of them by default.

    Returns
    -------
    xarray.DataTree
        The fit (layout in :mod:`pmabayes.inference.posterior`).

    Raises
    ------
    FitError
        When the data cannot be fitted, the experiments' inputs are of different
        kinds, or the chains belong to another fit.
    DataError
        When ``trials`` names an id the data do not hold, or data of several files.

    Warns
    -----
    ConvergenceWarning
        Once, when the budget ran out before the sampler converged.
    DisagreementWarning
        When several experiments disagree: their own MAPs are not compatible with one
        shared parameter set (the fit's ``map`` record holds the test,
        :func:`pmabayes.inference.search.experiments_agreement`). The fit goes on:
        :func:`pmabayes.diagnose` shows which parameters move between them.
    PoorFitWarning
        When the best fit misses more than a quarter of the motion, or ends worse
        than the static line the model contains (the fit's ``map`` record holds the
        numbers, :func:`pmabayes.inference.search.fit_quality`). The fit goes on.

    Examples
    --------
    Fit four of six repeated trials with a regulator lag added to the base model,
    keeping trials 5 and 6 for :func:`pmabayes.validate` (about 15 s):

    >>> import pmabayes
    >>> from pmabayes.data import load
    >>> data = load("muscle_a.csv")  # doctest: +SKIP
    >>> model = pmabayes.Model.for_dataset(data, effects=["regulator_lag"])  # doctest: +SKIP
    >>> tree = pmabayes.fit(data, model, trials=[1, 2, 3, 4])  # doctest: +SKIP
    >>> round(float(tree.posterior["tau_reg"].mean()), 3)  # doctest: +SKIP
    0.04

    :func:`pmabayes.inference.fitfile.save_fit` writes ``tree`` to a file that
    :func:`pmabayes.load_fit` reads back.
    """
    settings = FitSettings() if settings is None else settings
    if trials is not None:
        datasets = keep_trials(datasets, trials)
    if model is None:
        first = datasets if isinstance(datasets, Dataset) else next(iter(datasets), None)
        model = Model.for_dataset(first) if isinstance(first, Dataset) else Model()
    with show_progress("fit", settings.progress):
        return _fit(datasets, model, seed, settings, chains_dir, restart)


def _fit(datasets, model: Model, seed, settings: FitSettings, chains_dir, restart: bool
         ) -> xr.DataTree:
    """:func:`fit`, its progress switched."""
    start = time.perf_counter()
    posterior = build_posterior(model, datasets, substeps=settings.substeps,
                                tie_noise=settings.tie_noise, noise_model=settings.noise_model,
                                steady_state_tol_m=settings.steady_state_tol_m,
                                max_warmup_periods=settings.max_warmup_periods,
                                tie_segments=settings.tie_segments)
    _check_settings(settings, posterior)
    s_map, s_walkers, s_ppc = np.random.SeedSequence(seed).spawn(3)
    ens_seeds = [int(s.generate_state(1)[0]) for s in s_walkers.spawn(settings.n_ensembles)]
    say = Progress("fit")
    for name, lik, choice in zip(posterior.experiment_names, posterior.likelihoods,
                                 posterior.noise_choices, strict=True):
        if lik.n_repeats >= 2:
            say.say(f"noise of {name}: {choice.describe()}")
    with _chains_folder(chains_dir) as folder:
        chains = _Chains(folder, settings.n_ensembles,
                         _fingerprint(posterior, settings, seed))
        if restart:
            chains.clear()
        posterior, map_result, t_map, resumed = _map_or_resume(chains, posterior, s_map, say,
                                                               start)
        initials = _initial_walkers(posterior, map_result, ens_seeds, settings.n_walkers)
        t_sample = time.perf_counter()
        n_proc = settings.processes or min(settings.n_ensembles, local_cores())
        with Runner(n_proc, initializer=_init_worker, initargs=(posterior,),
                    tasks=settings.n_ensembles) as runner:
            _sample_rounds(posterior, chains, initials, ens_seeds, settings, runner, say)
        t_sampling = time.perf_counter() - t_sample
        diag = _convergence(chains.read(), posterior.names, settings)
        z, lp_z = chains.kept(diag)
    _warn_if_not_converged(diag)
    ensemble = np.repeat(np.arange(settings.n_ensembles), settings.n_walkers)
    tree = fit_tree(posterior, z, lp_z, ensemble, ppc_draws=settings.ppc_draws,
                    rng=np.random.default_rng(s_ppc))
    theta = posterior.to_natural(z.reshape(-1, posterior.ndim))
    rhat = _walker_rhat(theta.reshape(z.shape))
    # a noise sampled with the model is recorded at its posterior median (robust where
    # the MAP's noise is poorly polished); a noise from repeats at its mode
    noise = (posterior.noise_values(np.median(theta, axis=0))
             if any(posterior.noise_sampled(e) for e in range(posterior.n_experiments))
             else None)
    set_fit_info(tree, posterior, map_record=map_result.summary(),
                 convergence=diag.record(settings, posterior.names, rhat, resumed), seed=seed,
                 timings={"map": t_map, "sampling": t_sampling,
                          "total": time.perf_counter() - start}, noise_values=noise)
    return tree


def _check_settings(settings: FitSettings, posterior: Posterior) -> None:
    """What the settings cannot check alone: enough walkers for the parameters."""
    if settings.n_walkers < 2 * posterior.ndim:
        raise FitError(f"n_walkers must be at least {2 * posterior.ndim} (twice the "
                       f"{posterior.ndim} parameters), got {settings.n_walkers}")


def _map_or_resume(chains: _Chains, posterior: Posterior, seed: np.random.SeedSequence,
                   say: Progress, start: float
                   ) -> tuple[Posterior, MapResult, float, bool]:
    """The stamped MAP of resumable chains, or a fresh MAP that starts new ones; with the
    posterior they sample (a record's disturbance settled:
    :func:`~pmabayes.inference.disturbance.settle_disturbance`)."""
    saved = chains.saved_map()
    if saved is not None:
        say.say(f"resuming the chains in {chains.folder}")
        if saved[0].disturbance is not None:  # the bounds the chains were run with
            posterior = with_disturbance(posterior, saved[0].disturbance)
        if saved[0].period_reference_z is not None:  # the noise the chains were run with
            refer_periods(posterior, saved[0].period_reference_z)
        return (posterior, *saved, True)
    say.say("global search and MAP ...")
    rng = np.random.default_rng(seed)
    map_result = find_map(posterior, rng=rng)
    settled, map_result = settle_disturbance(posterior, map_result, rng=side_stream(rng, 1))
    if settled is not posterior:
        map_result.disturbance = [
            {k: lik.dataset.metadata[k] for k in ("disturbance_max_s", "disturbance_check")
             if k in lik.dataset.metadata} or None for lik in settled.likelihoods]
        posterior = settled
    t_map = time.perf_counter() - start
    say.say(f"MAP in {t_map:.1f} s: RMS cost {map_result.rms_cost_m * 1e6:.1f} µm "
            f"(global search {map_result.global_rms_cost_m * 1e6:.1f} µm)")
    if map_result.agreement is not None:
        say.say(f"MAP from the {map_result.agreement['start']}")
        text = disagreement_text(map_result.agreement)
        if text:
            warnings.warn(text[0].upper() + text[1:] + ".", DisagreementWarning, stacklevel=4)
    if map_result.quality is not None and map_result.quality["text"]:
        warnings.warn(map_result.quality["text"], PoorFitWarning, stacklevel=4)
    if map_result.period_reference_z is not None:
        for name, lik, choice in zip(posterior.experiment_names, posterior.likelihoods,
                                     posterior.noise_choices, strict=True):
            if lik.periods_referred:
                say.say(f"noise of {name} from its periods' residual at the MAP (the "
                        f"model's shakedown from rest removed): {choice.describe()}")
            elif lik.trials_referred:
                say.say(f"noise of {name} from its trials' residuals at the MAP, each "
                        "trial's model on its own input (the model's response to the inputs' "
                        f"differences removed): {choice.describe()}")
                check_trials(lik.referred_trials(), warn=True)
    chains.start(map_result, t_map)
    return posterior, map_result, t_map, False


def _initial_walkers(posterior: Posterior, map_result: MapResult, ens_seeds: list[int],
                     n_walkers: int) -> list[np.ndarray]:
    """Each ensemble's walkers, drawn from the Laplace approximation at the MAP."""
    initials = []
    for seed in ens_seeds:
        rng = np.random.default_rng(seed)
        pts = rng.multivariate_normal(map_result.z, map_result.covariance_z,
                                      size=n_walkers, method="eigh")
        lp = posterior.log_prob_z(pts)
        for _ in range(100):  # redraw any walker that starts outside the support
            bad = ~np.isfinite(lp)
            if not bad.any():
                break
            pts[bad] = rng.multivariate_normal(map_result.z, 0.25 * map_result.covariance_z,
                                               size=int(bad.sum()), method="eigh")
            lp[bad] = posterior.log_prob_z(pts[bad])
        initials.append(pts)
    return initials


def _warn_if_not_converged(diag: _Diagnostics) -> None:
    # said once, as a warning: a caller that reports it its own way (the CLI's
    # banner) filters ConvergenceWarning
    if not diag.converged:
        warnings.warn(
            "pmabayes fit did NOT converge: " + "; ".join(diag.messages)
            + ". The result is saved anyway; run longer (more steps) before trusting it.",
            ConvergenceWarning, stacklevel=3,
        )
