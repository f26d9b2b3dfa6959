"""The likelihood of an experiment's trials under a model and a noise model.

Each trial is the model's position plus noise, independent between trials. The noise
model is an object (:class:`pmabayes.inference.noise.NoiseModel`) the likelihood
delegates to: by default an AR(1) disturbance and white sensor noise, whose exact
likelihood comes from a Kalman filter (or, where the repeats reject that, the repeats'
AR(p); or a model asked for by name, such as Student-t white noise). For a Gaussian
noise the likelihood factorises into the trials' deviations from their mean, which do
not depend on the model and give the noise, and the trial mean's residual, which gives
the model. A record without repeats learns its noise from its periods, or with the
model under a bound on the noise's correlation time. Samples not observed (gaps, a
warm-up) are missing in the filter; trials with their own measured inputs are each
simulated on their own, their noise learnt from their residuals; a start may be
estimated. The documentation's page "The likelihood" (``docs/theory/likelihood.rst``)
gives the model, the factorisation and why.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from pmabayes.data import Dataset
from pmabayes.inference.noise.ar1 import (
    AR1_WHITE,
    NOISE_PARAMETERS,
    NOISE_PER_AMPLITUDE,
    _kalman_innovations,
    _kalman_loglik,
    _kalman_loglik_fixed_noise,
    _masked_loglik,
    _noise_loglik,
    ar1_noise,
    measurement_noise,
)
from pmabayes.inference.noise.ar_repeats import (
    MAX_AR_ORDER,
    ArFromRepeats,
    ArNoise,
    ar_noise_from_repeats,
    levinson,
)
from pmabayes.inference.noise.base import NoiseModel
from pmabayes.inference.noise.choice import (
    LEVEL_ADEQUATE,
    LJUNG_BOX_LAGS,
    NOISE_MODELS,
    NoiseChoice,
    _ljung_box_observed,
    ar1_whiteness_of_repeats,
    check_noise_model_name,
    choose_noise_model,
    ljung_box_statistic,
)
from pmabayes.model.codegen import state_effects
from pmabayes.model.model import Model
from pmabayes.model.parameters import Normal, Parameter
from pmabayes.model.simulator import position_reference, simulate_dataset, warmup_settings

__all__ = ["NOISE_PARAMETERS", "NOISE_SOURCES", "GUARD_FACTOR", "Likelihood", "JointLikelihood",
           "LikelihoodError", "ar1_noise", "measurement_noise", "NOISE_MODELS", "LEVEL_ADEQUATE",
           "MAX_AR_ORDER", "LJUNG_BOX_LAGS", "ljung_box_statistic", "levinson", "ArNoise",
           "ar_noise_from_repeats", "NoiseChoice", "check_noise_model_name",
           "ar1_whiteness_of_repeats", "choose_noise_model", "NOISE_PER_AMPLITUDE", "span",
           "START_WINDOW_S", "slow_disturbance_note", "at_fast_bound"]

#: The noise kernels, moved to :mod:`pmabayes.inference.noise.ar1`, still importable here
_KERNELS = (_kalman_innovations, _kalman_loglik, _kalman_loglik_fixed_noise, _masked_loglik,
            _noise_loglik, _ljung_box_observed)


@numba.njit(cache=True, error_model="numpy")
def _rms_by_time(y, xt):
    """RMS of ``y - xt[:, b]`` per column of ``xt`` ``(n, batch)``, in one pass over
    memory in its own order (NumPy's reduction across the strided axis is slow)."""
    n, batch = xt.shape
    out = np.zeros(batch)
    for k in range(n):
        yk = y[k]
        for b in range(batch):
            d = yk - xt[k, b]
            out[b] += d * d
    for b in range(batch):
        out[b] = math.sqrt(out[b] / n)
    return out


@numba.njit(cache=True, error_model="numpy")
def _rms_masked(y, xt, obs):
    """RMS over the samples seen in any trial of the mean, over the trials seen there, of
    ``y[r] - xt[:, r or 0, b]``; ``y`` ``(trials, n)``, ``xt`` ``(n, 1 or trials, batch)``,
    ``obs`` ``(trials, n)``. Returns ``(batch,)``."""
    n_trials, n = y.shape
    batch = xt.shape[2]
    own_x = xt.shape[1] > 1
    out = np.zeros(batch)
    mean = np.empty(batch)
    used = 0
    for k in range(n):
        seen = 0
        mean[:] = 0.0
        for r in range(n_trials):
            if obs[r, k]:
                seen += 1
                x_k = xt[k, r if own_x else 0]
                for b in range(batch):
                    mean[b] += y[r, k] - x_k[b]
        if seen:
            used += 1
            for b in range(batch):
                d = mean[b] / seen
                out[b] += d * d
    for b in range(batch):
        out[b] = math.sqrt(out[b] / max(used, 1))
    return out


#: What identifies the noise without the model, per experiment (see :class:`Likelihood`).
NOISE_SOURCES: tuple[str, ...] = ("trials", "periods", "record")

#: A disturbance whose spectrum stays flat up to this multiple of the input's upper
#: frequency is fast: one record separates it from the model's misfit. A slower one,
#: in a record without repeats, is confounded with slow physics
#: (:attr:`Likelihood.rho_flat`, :func:`slow_disturbance_note`).
GUARD_FACTOR: float = 10.0



def _noise_repeats(dataset: Dataset, model_position_m: np.ndarray | None = None
                   ) -> tuple[str, np.ndarray]:
    """The noise source of a data set and the repeated series it offers.

    Trials when there are two or more; else the periods of a periodic record (all
    of them when it starts in steady state, from the second on when it starts from
    rest); else the record alone. Given the model's positions on a record that
    starts from rest, its periods are those of the residual, record minus model:
    the model's own change from period to period (its shakedown) is then not taken
    for noise (see :meth:`Likelihood.refer_periods_to`). Given the model's positions
    on each trial (``(n_trials, n_samples)``, trials with their own inputs), the
    trials are those of the residual: the model's response to the inputs'
    differences is not taken for noise either. :func:`_repeat_mask` says which of
    their samples are observed.
    """
    if dataset.n_trials >= 2:
        y = np.ascontiguousarray(dataset.position_m)
        if model_position_m is not None:
            y = y - np.asarray(model_position_m, dtype=float).reshape(y.shape)
        return "trials", y
    y = dataset.position_m[0]
    if model_position_m is not None and not dataset.starts_in_steady_state:
        y = y - np.asarray(model_position_m, dtype=float).reshape(-1)
    segs = _record_periods(dataset, y)
    if segs is not None:
        return "periods", np.ascontiguousarray(segs)
    return "record", np.ascontiguousarray(y[None, :])


def _record_periods(dataset: Dataset, series: np.ndarray) -> np.ndarray | None:
    """A single record's ``series`` (``(n_samples,)``) cut into the periods that are its
    repeats, ``(periods, period_samples)``; None when it has fewer than two."""
    period, n_per = dataset.period_samples, dataset.n_periods
    if period is None or n_per is None:
        return None
    first = 0 if dataset.starts_in_steady_state else 1  # from rest: the first is a transient
    if n_per - first < 2:
        return None
    return series[first * period: n_per * period].reshape(n_per - first, period)


def _repeat_mask(dataset: Dataset, observed: np.ndarray | None) -> np.ndarray | None:
    """Which samples of :func:`_noise_repeats`' series are observed (``observed``:
    the trials', ``(n_trials, n_samples)``), in their shape; None when all are."""
    if observed is None or dataset.n_trials >= 2:
        return observed
    segs = _record_periods(dataset, observed[0])
    return observed[:1] if segs is None else segs


def at_fast_bound(likelihood: Likelihood, rho: float) -> bool:
    """Whether a record's noise sits at its fast bound.

    Parameters
    ----------
    likelihood : Likelihood
        The record's.
    rho : float
        The identified noise's lag-one correlation.

    Returns
    -------
    bool
        True for a record without repeats whose ``rho`` is within 1% of
        ``1 - rho_flat`` of :attr:`Likelihood.rho_flat`; False for data with repeats.
    """
    return likelihood.noise_source == "record" and _at_bound(likelihood.rho_flat, rho)


def _at_bound(bound: float, rho: float) -> bool:
    """``rho`` within 1% of ``1 - bound`` of ``bound``."""
    return bound - float(rho) <= 0.01 * (1.0 - bound)


def slow_disturbance_note(likelihood: Likelihood, rho: float) -> str:
    """What a record without repeats cannot tell, when its disturbance is slow.

    Parameters
    ----------
    likelihood, rho : Likelihood, float
        As :func:`at_fast_bound`'s.

    Returns
    -------
    str
        A sentence (no final full stop) for a record without repeats whose noise was
        allowed to be slow (its metadata's ``disturbance_check``, written by
        :func:`pmabayes.inference.disturbance.settle_disturbance`, or a declared
        ``disturbance_max_s``), or whose noise sits at the fast bound; an empty string
        otherwise.
    """
    if likelihood.noise_source != "record":
        return ""
    meta = likelihood.dataset.metadata
    check = meta.get("disturbance_check")
    dt = likelihood.dataset.dt_s
    tau_flat = -dt / math.log(likelihood.rho_flat)
    f_in = max(likelihood.input_frequency_hz,
               likelihood.dataset.sample_rate_hz / likelihood.n_samples)
    fast = (f"a correlation time of {tau_flat * 1e3:.2g} ms (flat up to {GUARD_FACTOR:g} "
            f"times the input's {f_in:.3g} Hz)")
    if check is not None and check.get("kept") == "slow":
        tau = -dt / math.log(min(max(float(rho), 1e-12), 0.999999))
        return (f"the record's disturbance is slow: a correlation time of {tau * 1e3:.3g} ms, "
                f"beyond the fast bound's {tau_flat * 1e3:.2g} ms, allowed because it leaves "
                f"the model's own error as it was ({check['rms_slow_m'] * 1e6:.4g} µm against "
                f"{check['rms_fast_m'] * 1e6:.4g} µm with a fast one, at most "
                f"{check['ratio_allowed']:g}x allowed) and the residual white under it "
                f"(Ljung-Box p = {check['ljung_box_p_slow']:.2g}). Slow physics the model "
                "lacks that leaves the fit as it was would look the same on one record: "
                "repeat the record, or make it periodic, to tell them apart")
    if check is not None:
        slow_rms, p = check.get("rms_slow_m"), check.get("ljung_box_p_slow")
        if slow_rms is None:
            what = "its fit was refused: it takes in misfit"
        elif slow_rms > check["ratio_allowed"] * check["rms_fast_m"]:
            what = (f"it left the model's own error at {slow_rms * 1e6:.4g} µm against "
                    f"{check['rms_fast_m'] * 1e6:.4g} µm: it takes in misfit")
        else:
            p_words = "< 1e-15" if p < 1e-15 else f"= {p:.2g}"
            what = (f"it left the residual coloured (Ljung-Box p {p_words}): it explains "
                    "nothing the fast one does not")
        return (f"the disturbance identified with the model sits at its fast bound, {fast}. "
                f"A slow one (up to {check['bound_s']:.3g} s) was tried and {what}, so the "
                "noise is kept fast and the slow residual shows as misfit (slow physics the "
                "model lacks, or a disturbance one record cannot tell from it). Repeat the "
                "record, or make it periodic, to separate them")
    declared = meta.get("disturbance_max_s")
    if declared is not None:
        if not _at_bound(likelihood.rho_max, rho):
            return ""
        return (f"the disturbance identified with the model sits at the bound the data "
                f"declare (disturbance_max_s = {declared:g} s): a slower one shows as misfit")
    if not at_fast_bound(likelihood, rho):
        return ""
    return (f"the disturbance identified with the model sits at its bound, {fast}: a "
            "slower disturbance would reach into the input's time scales, and one record "
            "cannot tell it from slow physics the model lacks, so the noise is kept fast and "
            "such a disturbance shows as misfit. Repeat the record, or make it periodic, to "
            "separate them")


class LikelihoodError(ValueError):
    """The data cannot be fitted as given (too few trials, no motion, wrong rig)."""


class Likelihood:
    """Likelihood of the trials of one experiment.

    The noise is AR(1) + white (Kalman filter), or an AR(p) of the repeats once
    :meth:`use_ar_noise` set one (see the module's docstring). Samples not observed
    (gaps in a lab's clock, a declared ``warmup_s``) are missing in the likelihood:
    the filter predicts across them. Trials may have their own inputs (measured
    pressures): each is simulated on its own, and the likelihood is the sum of each
    trial's. A start declared ``"estimate"`` is simulated from the ``start`` given
    (:meth:`start_parameters`).

    Parameters
    ----------
    model : Model
        The composed model, on this experiment's rig.
    dataset : Dataset
        One experiment: one or more trials, sharing the input (the commanded pressure
        or force) or each with its own (a measured one).
    substeps : int
        Simulator substeps per sample (see :func:`pmabayes.simulate`).
    steady_state_tol_m, max_warmup_periods : optional
        The periodic steady state's settings where the data start in it, over the
        sidecar's (:func:`pmabayes.model.simulator.warmup_settings`).

    Attributes
    ----------
    noise_source : str
        What identifies the noise without the model (:data:`NOISE_SOURCES`):
        ``"trials"`` (two or more repeated trials), ``"periods"`` (one record of a
        declared periodic input, its periods in steady state taken as repeats) or
        ``"record"`` (one record without repeats: the noise is identified jointly
        with the model, under :meth:`noise_parameters`' bound).
    n_repeats : int
        The number of repeated series the noise is learnt from without the model
        (trials or periods; 1 for ``"record"``).
    columns : numpy.ndarray or None
        Where a posterior of several experiments gives this one's model parameters
        their own columns (per-experiment parameters, rig values of its own): the
        columns of the posterior's full parameter array that :meth:`simulate` takes
        (:meth:`pmabayes.inference.density.Posterior.full_theta`); None takes the
        array as this model's.
    own_inputs : bool
        Whether the trials have inputs of their own (measured ones, which differ by
        the regulator's error): each is simulated on its own input
        (:attr:`n_outputs`), the likelihood is the sum of each trial's, and the noise
        is learnt from the trials referred to the model (:meth:`refer_periods_to`).
    observed : numpy.ndarray or None
        ``(n_trials, n_samples)``, True where a sample enters the likelihood: observed
        (:attr:`pmabayes.data.Dataset.observed`) and after the declared warm-up
        (:attr:`pmabayes.data.Dataset.warmup_s`). None when every sample does.
    per_trial : bool
        Whether the likelihood is the sum of each trial's: trials with their own
        inputs, trials observed at different samples, or a noise model whose
        likelihood does not split (``splits_mean`` of
        :class:`~pmabayes.inference.noise.NoiseModel`). Otherwise the trial mean and
        the contrasts split it (see the module's docstring).
    noise : NoiseModel
        The noise model the likelihood delegates to (:meth:`use_noise`); AR(1) + white
        by default.
    n_outputs : int
        Values of one model output (:meth:`simulate`): ``n_samples``, or ``n_trials *
        n_samples`` with :attr:`own_inputs` (trial after trial).
    referred : bool
        Whether the repeats are those of the residual at a model's positions
        (:meth:`refer_periods_to`) rather than of the data themselves.

    Raises
    ------
    LikelihoodError
        With an input kind that does not match the rig, positions that never change,
        or a trial with no sample left for the likelihood.
    """

    def __init__(self, model: Model, dataset: Dataset, *, substeps: int = 1,
                 steady_state_tol_m: float | None = None,
                 max_warmup_periods: int | None = None) -> None:
        where = dataset.source or "the data set"
        if dataset.input_name != model.rig.input_name:
            raise LikelihoodError(
                f"{where}: the input column is {dataset.input_name!r} but the model's rig "
                f"({model.rig.name}) expects {model.rig.input_name!r}; use a matching rig"
            )
        self.own_inputs = not bool(np.all(dataset.input == dataset.input[0]))
        observed = dataset.counted
        empty = ~observed.any(axis=1)
        if empty.any():
            raise LikelihoodError(
                f"{where}: trial {int(dataset.trial_ids[np.argmax(empty)])} has no sample "
                f"after the warm-up of {dataset.warmup_s:g} s (warmup_s); shorten the warm-up")
        complete = bool(observed.all())
        motion = float(np.ptp(dataset.position_m if complete else dataset.position_m[observed]))
        if motion == 0.0:
            raise LikelihoodError(
                f"{where}: every position is {float(dataset.position_m.flat[0])!r} m, so there is "
                "nothing to fit; check the position column and that the sensor was recording"
            )
        self.model = model
        self.dataset = dataset
        self.substeps = int(substeps)
        self.warmup = (warmup_settings(dataset, steady_state_tol_m, max_warmup_periods)
                       if dataset.starts_in_steady_state else (None, None))
        position_reference(dataset)  # a bad declaration fails here, not in the search
        self.columns: np.ndarray | None = None
        self.n_trials, self.n_samples = dataset.position_m.shape
        self.observed = None if complete else observed
        # the data's own reasons for a sum of each trial's likelihood (see per_trial)
        self._per_trial_data = self.n_trials >= 2 and (
            self.own_inputs or not (complete or bool(np.all(observed == observed[0]))))
        self.n_outputs = self.n_samples * (self.n_trials if self.own_inputs else 1)
        self.input = np.ascontiguousarray(dataset.input[0])
        self.y_mean = dataset.mean_position_m
        self._trials = np.ascontiguousarray(
            dataset.position_m if complete else np.where(observed, dataset.position_m, 0.0))
        # the split's trial mean and its samples (a mask shared by the trials)
        self._mean_obs = None if complete or self._per_trial_data else observed[:1]
        self._y_mean = (self.y_mean if self._mean_obs is None
                        else np.where(self._mean_obs[0], self._trials.mean(axis=0), 0.0))
        self.noise_source, repeats = _noise_repeats(dataset)
        self.n_repeats = repeats.shape[0]
        self.referred = False
        self._set_repeats(repeats, _repeat_mask(dataset, self.observed))
        self.motion_m = motion
        self.noise: NoiseModel = AR1_WHITE
        self._start = (_start_priors(self) if dataset.initial_state == "estimate" else ())

    def _set_repeats(self, repeats: np.ndarray, masks: np.ndarray | None = None) -> None:
        # where the repeats are not all observed, the contrasts take the samples seen
        # in every repeat; the others are missing for them
        both = None if masks is None else masks.all(axis=0)
        self._contrast_obs = None if both is None or both.all() else both[None, :]
        if both is not None:
            repeats = np.where(both, repeats, 0.0)
        self._repeats = repeats
        if self.n_repeats >= 2:
            # Helmert contrasts: R - 1 orthonormal combinations of the repeats that
            # remove their mean; each is a series of the noise process alone
            r = self.n_repeats
            helmert = np.zeros((r - 1, r))
            for j in range(r - 1):
                helmert[j, : j + 1] = 1.0
                helmert[j, j + 1] = -(j + 1.0)
                helmert[j] /= math.sqrt((j + 1.0) * (j + 2.0))
            self._contrasts = np.ascontiguousarray(helmert @ repeats)
            self._d = repeats - repeats.mean(axis=0)
        else:
            self._contrasts = np.zeros((0, self.n_samples))
            self._d = np.zeros((0, self.n_samples))

    @property
    def periods_from_rest(self) -> bool:
        """Whether the noise comes from the periods of a record that starts from rest.

        Such a record's periods after the first are not yet the same for the model
        either: hysteresis shakes down over many periods (at the paper's values by
        about 0.84 a period). Their deviations then hold the model's own drift as
        well as the noise, until :meth:`refer_periods_to` removes it.
        """
        return self.noise_source == "periods" and not self.dataset.starts_in_steady_state

    @property
    def refers_to_model(self) -> bool:
        """Whether the repeats must be referred to the model (:meth:`refer_periods_to`)
        for their deviations to be noise alone: the periods of a record from rest
        (:attr:`periods_from_rest`), or trials with their own inputs, whose model
        outputs differ by the response to the inputs' differences."""
        return self.periods_from_rest or (self.noise_source == "trials" and self.own_inputs)

    @property
    def periods_referred(self) -> bool:
        """Whether the periods are those of the residual at a model's positions."""
        return self.referred and self.noise_source == "periods"

    @property
    def trials_referred(self) -> bool:
        """Whether the trials (with their own inputs) are those of the residual at a
        model's positions."""
        return self.referred and self.noise_source == "trials"

    @property
    def referred_noise_floor_m(self) -> float:
        """The noise floor of trials referred to the model (:attr:`trials_referred`):
        the RMS error a perfect model would have against the trial mean, from the
        spread of the trials' residuals (over the samples every trial observed); NaN
        otherwise."""
        if not self.trials_referred:
            return math.nan
        d = self._d if self._contrast_obs is None else self._d[:, self._contrast_obs[0]]
        var = float(np.mean(np.sum(d * d, axis=0) / (self.n_repeats - 1)))
        return math.sqrt(var / self.n_repeats)

    @property
    def periods_noise_floor_m(self) -> float:
        """The noise floor of a single periodic record, from the periods its noise is
        learnt from (referred to the model once :meth:`refer_periods_to` ran): the root
        of the mean over the period's samples of their deviations' variance, not divided
        (the record is one series). The overall floor of
        :func:`pmabayes.criticism.bands.band_errors` on the same periods; NaN when the
        noise does not come from periods.
        """
        if self.noise_source != "periods" or self.n_repeats < 2:
            return math.nan
        d = self._d if self._contrast_obs is None else self._d[:, self._contrast_obs[0]]
        return math.sqrt(float(np.mean(np.sum(d * d, axis=0) / (self.n_repeats - 1))))

    def refer_periods_to(self, model_position_m: np.ndarray) -> None:
        """Take the noise from the repeats of the residual, data minus model.

        For a periodic record that starts from rest (:attr:`periods_from_rest`), or
        trials with their own inputs (:attr:`own_inputs`); otherwise nothing changes.
        The model's change from period to period, or its response to the trials'
        differing inputs, is then not counted as noise, while any misfit that the
        repeats share still cancels in the deviations, as for the raw repeats: the
        noise stays what the model cannot explain away.
        :func:`pmabayes.inference.search.find_map` calls this at its first optimum
        and estimates the noise again.

        Parameters
        ----------
        model_position_m : numpy.ndarray
            The model's positions, ``(n_outputs,)`` (:meth:`simulate`'s row).
        """
        if not self.refers_to_model:
            return
        x = np.asarray(model_position_m, dtype=float).reshape(-1)
        if x.shape != (self.n_outputs,) or not np.all(np.isfinite(x)):
            raise LikelihoodError(f"{self.dataset.source or 'the data set'}: the model's "
                                  f"positions must be {self.n_outputs} finite values")
        repeats = _noise_repeats(self.dataset, x)[1]
        self._referred = repeats
        self._set_repeats(repeats, _repeat_mask(self.dataset, self.observed))
        self.referred = True

    def referred_trials(self) -> Dataset:
        """The trials referred to the model (:attr:`trials_referred`), as a data set:
        each trial's residual at the model's positions, for the check that they are
        exchangeable (:func:`pmabayes.inference.trials.check_trials`).

        Returns
        -------
        Dataset

        Raises
        ------
        LikelihoodError
            If the trials have not been referred to a model.
        """
        ds = self.dataset
        if not self.trials_referred:
            raise LikelihoodError(f"{ds.source or 'the data set'}: its trials have not been "
                                  "referred to a model (refer_periods_to)")
        return Dataset(time_s=ds.time_s, input=ds.input, position_m=self._referred,
                       trial_ids=ds.trial_ids, input_name=ds.input_name,
                       source=f"{ds.source or 'the data set'} (the trials' residuals)",
                       observed=ds.observed if ds.n_missing else None)

    def start_parameters(self) -> tuple[Parameter, ...]:
        """The parameters of an estimated start, with their priors; none otherwise.

        For a data set whose ``initial_state`` is ``"estimate"``: the position
        ``x0_m`` (before measurement effects), velocity ``v0_m_s`` and hysteretic force
        at the first sample, the last as ``z0_offset_n``, its offset from the balance
        of forces there (:func:`pmabayes.simulate`'s ``initial_values``). Their
        priors come from the first :data:`START_WINDOW_S` of the trial mean (at least
        five samples): a parabola fitted to it gives the position (its value at the
        start) and the velocity (its slope there), each normal with a spread of three
        standard errors (three times the parabola's residual for the position, its
        slope itself for the velocity, if larger), at least 0.1% of the motion for the
        position and the record's mean speed for the velocity; the force is normal
        about the balance with the actuator's whole range of force as its spread (area
        times the pressure's range, or the force's range). Then each effect state's
        value there, with the prior its effect gives
        (:meth:`~pmabayes.model.effects.base.Effect.start_state`: a degrading law's
        dissipated energy, a creep element's stretch; a state its effect gives none is
        at 0, at rest), in the kernel's order (:func:`full_start`). Shared by the
        trials; the global search keeps them at their prior means, the polish and the
        sampler free them.

        Returns
        -------
        tuple of Parameter
        """
        return self._start

    def start_from(self, start: np.ndarray | None, model: Model) -> np.ndarray | None:
        """A start of another model's likelihood on this data set (``(3 + k,)`` or
        ``(batch, 3 + k)``, :meth:`start_parameters` of ``model``) in this one's
        columns: the position, velocity and ``z`` offset as they are, each effect's
        state from the same effect's, and a state ``model`` lacks at its prior mean
        here (a candidate effect's, tested at its null where the state does not act).

        Parameters
        ----------
        start : numpy.ndarray or None
        model : Model
            The model ``start`` is of.

        Returns
        -------
        numpy.ndarray or None
            ``(batch, len(start_parameters()))``; None without a start or when this
            data set's start is not estimated.
        """
        if start is None or not self._start:
            return None
        start = np.atleast_2d(np.asarray(start, dtype=float))
        theirs = {e.name: 3 + j for j, e in enumerate(estimated_states(model))}
        out = np.broadcast_to(self.start_defaults(), (start.shape[0], len(self._start))).copy()
        out[:, :3] = start[:, :3]
        for j, e in enumerate(estimated_states(self.model)):
            if e.name in theirs:
                out[:, 3 + j] = start[:, theirs[e.name]]
        return out

    def start_defaults(self) -> np.ndarray:
        """The start's prior means ``(3 + k,)`` (an estimated start; empty otherwise)."""
        return np.array([p.default for p in self._start])

    # -- the noise model ----------------------------------------------------------
    @property
    def contrasts(self) -> np.ndarray:
        """The repeats' Helmert contrasts ``(n_repeats - 1, length)``: series of the
        noise alone (none for a record without repeats)."""
        return self._contrasts

    @property
    def per_trial(self) -> bool:
        """Whether the likelihood is the sum of each trial's (see the class)."""
        return self._per_trial_data or (self.n_trials >= 2 and not self.noise.splits_mean)

    def use_noise(self, noise: NoiseModel) -> None:
        """Use a noise model for :meth:`mean_log_likelihood`, :meth:`log_likelihood`,
        :meth:`pointwise`, :meth:`stretch_pointwise`, :meth:`whiten` and
        :meth:`innovations`; their noise parameters are then the model's
        (:meth:`noise_parameters`). :meth:`deviation_log_likelihood` and
        :meth:`whiten_contrasts` stay AR(1) + white, which
        :func:`pmabayes.inference.noise.estimate_noise` and the noise check need.

        Parameters
        ----------
        noise : NoiseModel

        Raises
        ------
        LikelihoodError
            For a model that does not take samples not observed, on data with some.
        """
        if not isinstance(noise, NoiseModel):
            raise TypeError(f"noise must be a NoiseModel, got {type(noise).__name__}")
        if not noise.takes_missing and self.observed is not None:
            raise LikelihoodError(
                f"{self.dataset.source or 'the data set'}: samples not observed (gaps, a "
                f"warm-up) leave AR(1) + white as the noise model: {noise.label} takes "
                "complete series only (see choose_noise_model)")
        self.noise = noise

    def use_ar_noise(self, ar: ArNoise | None) -> None:
        """Use the AR(p) noise of the repeats instead of AR(1) + white, or go back
        (:meth:`use_noise` with :class:`~pmabayes.inference.noise.ArFromRepeats`).

        Parameters
        ----------
        ar : ArNoise or None
            None for AR(1) + white.
        """
        if ar is not None and not isinstance(ar, ArNoise):
            raise TypeError(f"ar must be an ArNoise or None, got {type(ar).__name__}")
        self.use_noise(AR1_WHITE if ar is None else ArFromRepeats(ar))

    @property
    def ar_noise(self) -> ArNoise | None:
        """The AR(p) of the repeats the likelihood uses, or None (another noise model)."""
        return getattr(self.noise, "ar", None)

    @property
    def noise_model_name(self) -> str:
        """The noise model of the likelihood in words."""
        return self.noise.label

    # -- the noise bound for records without repeats ----------------------------
    @property
    def input_frequency_hz(self) -> float:
        """The input's upper frequency: 99% of its variance lies below it.

        Where a model's misfit lives (with the harmonics that hysteresis makes of
        it); a disturbance slower than one flat far above it (:attr:`rho_flat`) is
        confounded with slow missing physics in a record without repeats.
        """
        u = self.input - self.input.mean()
        power = np.abs(np.fft.rfft(u)) ** 2
        power[0] = 0.0
        total = power.sum()
        if not total > 0:  # a constant input: no time scale of its own
            return 0.5 * self.dataset.sample_rate_hz
        freq = np.fft.rfftfreq(self.n_samples, self.dataset.dt_s)
        k = int(np.searchsorted(np.cumsum(power) / total, 0.99))
        return float(freq[min(k, freq.size - 1)])

    @property
    def rho_flat(self) -> float:
        """Largest lag-one correlation of a disturbance whose spectrum is flat far above
        the input's band.

        The correlation time ``1 / (2 pi GUARD_FACTOR f_in)`` (``f_in``:
        :attr:`input_frequency_hz`): the spectrum is flat up to ``GUARD_FACTOR`` times
        the input's upper frequency. A record without repeats whose noise is slower
        than this cannot tell it from slow physics the model lacks
        (:func:`slow_disturbance_note`).
        """
        f_in = max(self.input_frequency_hz, self.dataset.sample_rate_hz / self.n_samples)
        tau_flat = 1.0 / (2.0 * math.pi * GUARD_FACTOR * f_in)
        return float(min(math.exp(-self.dataset.dt_s / tau_flat), 0.999999))

    @property
    def rho_max(self) -> float:
        """Largest lag-one correlation the noise of a record without repeats may have.

        The data's metadata ``disturbance_max_s`` where given (declared by a lab, or
        kept by :func:`pmabayes.inference.disturbance.settle_disturbance`); else
        :attr:`rho_flat`: the disturbance's spectrum flat up to :data:`GUARD_FACTOR`
        times the input's upper frequency, so that the misfit of slow physics stays in
        the residual, where the adequacy check sees it. Returned for any noise source;
        used for ``"record"``.
        """
        declared = self.dataset.metadata.get("disturbance_max_s")
        if declared is None:
            return self.rho_flat
        return float(min(math.exp(-self.dataset.dt_s / float(declared)), 0.999999))

    def noise_parameters(self) -> tuple[Parameter, ...]:
        """The noise parameters with their priors for this experiment: its noise
        model's (:meth:`pmabayes.inference.noise.NoiseModel.parameters`).

        For AR(1) + white, :data:`NOISE_PARAMETERS`, with the noise's scale on the
        data's for a force-input rig (:data:`NOISE_PER_AMPLITUDE`), except for a
        record without repeats (``noise_source == "record"``): there ``rho_noise`` is
        bounded by :attr:`rho_max` (uniform prior on ``[-rho_max, rho_max]``), a
        correlation time far below the input's time scales unless the data allow a
        slower one; a noise at that bound is said in the verdicts
        (:func:`slow_disturbance_note`).

        Returns
        -------
        tuple of Parameter
        """
        return self.noise.parameters(self)

    # -- model output ---------------------------------------------------------
    def simulate(self, theta: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
        """Model positions ``(batch, n_outputs)`` for a full parameter array.

        The array is the posterior's, of which :attr:`columns` are this model's, where
        set. With :attr:`own_inputs`, each trial on its own input, trial after trial
        (``n_trials * n_samples`` values). ``start`` is an estimated start's
        ``(batch, 3)`` values (:meth:`start_parameters`); without it such a start is at
        its prior means (for callers that do not sample it).
        """
        theta = np.atleast_2d(theta)
        if self.columns is not None:
            theta = np.ascontiguousarray(theta[:, self.columns])
        if self._start and start is None:
            start = np.broadcast_to(self.start_defaults(), (theta.shape[0], len(self._start)))
        x = simulate_dataset(self.model, theta, self.dataset, substeps=self.substeps,
                             steady_state_tol_m=self.warmup[0],
                             max_warmup_periods=self.warmup[1], per_trial=self.own_inputs,
                             initial_values=(full_start(self.model, start) if self._start
                                             else None))
        return x.reshape(x.shape[0], -1) if self.own_inputs else x

    def _by_trial(self, x: np.ndarray) -> np.ndarray:
        """Model outputs ``(batch, n_outputs)`` as ``(batch, 1 or n_trials, n_samples)``."""
        x = np.atleast_2d(x)
        return x.reshape(x.shape[0], -1, self.n_samples)

    def rms_cost(self, x: np.ndarray) -> np.ndarray:
        """The paper's cost: RMS of the trial mean minus the model, per batch member.

        Over the samples observed (any trial), each the mean over the trials observed
        there of data minus model (their own model, with :attr:`own_inputs`).
        """
        x = np.atleast_2d(x)
        if self.observed is not None or self.own_inputs:
            obs = (self.observed if self.observed is not None
                   else np.ones(self._trials.shape, dtype=bool))
            xt = np.ascontiguousarray(np.transpose(self._by_trial(x), (2, 1, 0)))
            return _rms_masked(self._trials, xt, obs)
        if x.shape[0] > 1 and x.T.flags.c_contiguous:  # the simulator's own layout
            return _rms_by_time(self.y_mean, x.T)
        return np.sqrt(np.mean((self.y_mean - x) ** 2, axis=1))

    # -- likelihood -------------------------------------------------------------

    def deviation_log_likelihood(self, sigma, rho, white) -> np.ndarray:
        """Log-likelihood of the deviations from the trial mean (model-free).

        The deviations are ``R - 1`` independent series of the noise process in
        disguise: their Helmert contrasts. The repeats are the trials, or the
        periods of a single periodic record (:attr:`noise_source`); a record
        without repeats has none (the result is 0). The contrasts take the samples
        observed in every repeat; the others are missing for them.

        Always under AR(1) + white: :func:`pmabayes.inference.noise.estimate_noise`
        learns that noise from the repeats, whatever the likelihood's noise model.

        Parameters
        ----------
        sigma, rho, white : array_like
            Noise parameters (``sigma_noise_m``, ``rho_noise``, ``sigma_white_m``),
            scalars or ``(batch,)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        batch = np.broadcast(np.asarray(sigma), np.asarray(rho), np.asarray(white)).size
        return self._contrasts_log_likelihood(AR1_WHITE, (sigma, rho, white), batch)

    def _contrasts_log_likelihood(self, noise: NoiseModel, params: tuple, batch: int
                                  ) -> np.ndarray:
        """The contrasts' log density under ``noise``, ``(batch,)`` (0 without repeats)."""
        if not self._contrasts.shape[0]:
            return np.zeros(batch)
        zero = np.zeros((1, 1, self._contrasts.shape[1]))
        return noise.log_likelihood(self._contrasts, zero, 1.0, noise.broadcast(params, batch),
                                    self._contrast_obs).sum(axis=1)

    def mean_log_likelihood(self, x: np.ndarray, *noise) -> np.ndarray:
        """Log-likelihood of the data given the model: the part that depends on it.

        The density of ``sqrt(R) (ybar - x)``, one more series of the noise process
        and the orthonormal complement of the contrasts, so that it adds to
        :meth:`deviation_log_likelihood` exactly, under the noise model (:attr:`noise`:
        AR(1) + white by a Kalman filter, the repeats' AR(p), ...). Where the trial
        mean does not split the likelihood (:attr:`per_trial`: trials with their own
        inputs, or observed at different samples, or a noise model that does not
        split), the sum of each trial's likelihood.

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(batch, n_outputs)``.
        *noise : array_like
            The noise parameters (:meth:`noise_parameters`' order: ``sigma``, ``rho``,
            ``white`` for AR(1) + white), scalars or ``(batch,)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        x = np.atleast_2d(x)
        if self.per_trial:
            return self.pointwise(x, *noise).sum(axis=1)
        y = self.y_mean if self._mean_obs is None else self._y_mean
        return self.noise.log_likelihood(y[None, :], x[:, None, :], math.sqrt(self.n_trials),
                                         self.noise.broadcast(noise, x.shape[0]),
                                         self._mean_obs)[:, 0]

    def log_likelihood(self, x: np.ndarray, *noise) -> np.ndarray:
        """Total log-likelihood of all trials, per batch member.

        Equal to :meth:`deviation_log_likelihood` plus :meth:`mean_log_likelihood`
        for repeated trials; for a single record (periodic or not) the record's
        likelihood, :meth:`mean_log_likelihood` (its periods identify the noise but
        are not data beside the record); for :attr:`per_trial` trials the sum of each
        trial's, :meth:`mean_log_likelihood` too.

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(batch, n_outputs)``.
        *noise : array_like
            As :meth:`mean_log_likelihood`'s.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``, the total.
        """
        x = np.atleast_2d(x)
        mean = self.mean_log_likelihood(x, *noise)
        if self.noise_source != "trials" or self.per_trial:
            return mean
        return self._contrasts_log_likelihood(self.noise, noise, x.shape[0]) + mean

    def whiten(self, v: np.ndarray, *noise) -> np.ndarray:
        """Standardised innovations of ``sqrt(R) v`` under the noise model (AR(1) +
        white: the Kalman filter's).

        Linear in ``v``. Applied to the trial mean's residual it gives
        :meth:`innovations`; applied to sensitivities, their whitened versions. NaN
        at samples no trial observed (the filter predicts across them).

        Parameters
        ----------
        v : numpy.ndarray
            A series on the data's time grid, ``(n_samples,)``.
        *noise : float
            The noise parameters.

        Returns
        -------
        numpy.ndarray
            ``(n_samples,)``.
        """
        v = np.ascontiguousarray(np.asarray(v, dtype=float).reshape(-1))
        seen = (None if self.observed is None
                else np.ascontiguousarray(self.observed.any(axis=0)))
        return self.noise.whiten(v, math.sqrt(self.n_trials), noise, seen)

    def whiten_contrasts(self, sigma: float, rho: float, white: float) -> list[np.ndarray]:
        """The repeats' contrasts (:attr:`contrasts`) whitened by AR(1) + white.

        Each is a series of the noise alone on the repeats' own grid: the trials'
        (``n_samples``), or one period for the periods of a single record. The filter
        takes the samples observed in every repeat, as
        :meth:`deviation_log_likelihood` does, and predicts across the others (NaN
        there).

        Parameters
        ----------
        sigma, rho, white : float
            Noise parameters.

        Returns
        -------
        list of numpy.ndarray
            One whitened series per contrast (none without repeats).
        """
        seen = (None if self._contrast_obs is None
                else np.ascontiguousarray(self._contrast_obs[0]))
        return [AR1_WHITE.whiten(c, 1.0, (sigma, rho, white), seen) for c in self._contrasts]

    def innovations(self, x: np.ndarray, *noise) -> np.ndarray:
        """Standardised innovations of the trial mean's residual under the noise model.

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(n_samples,)``.
        *noise : float
            The noise parameters.

        Returns
        -------
        numpy.ndarray
            ``(n_samples,)``; independent N(0, 1) when the model describes the data
            (NaN where no trial is observed).
        """
        return self.whiten(self.y_mean - np.asarray(x, dtype=float).reshape(-1), *noise)

    def pointwise(self, x: np.ndarray, *noise) -> np.ndarray:
        """Log-likelihood of each trial, ``(batch, n_trials)``; sums to :meth:`log_likelihood`.

        Parameters
        ----------
        x, *noise : numpy.ndarray, array_like
            As :meth:`mean_log_likelihood`'s.

        Returns
        -------
        numpy.ndarray
            ``(batch, n_trials)``.
        """
        x = np.atleast_2d(x)
        return self.noise.log_likelihood(self._trials, self._by_trial(x), 1.0,
                                         self.noise.broadcast(noise, x.shape[0]), self.observed)

    def stretch_pointwise(self, x: np.ndarray, *noise_and_stretches) -> np.ndarray | None:
        """Log-likelihood of each of ``n_stretches`` contiguous stretches of a single record
        given the rest of it, ``(batch, n_stretches)``: the units of a leave-one-out
        estimate where there is only one trial to leave out.

        ``log p(y_k | y_-k) = log p(y) - log p(y_-k)``, exact under the noise model: it
        takes the stretch left out as not observed (the Kalman filter predicts across it).

        Parameters
        ----------
        x : numpy.ndarray
            Model positions ``(batch, n_outputs)``.
        *noise_and_stretches
            The noise parameters (scalars or ``(batch,)``), then the number of
            stretches (2 or more).

        Returns
        -------
        numpy.ndarray or None
            None for two or more trials (leave out trials instead) or under a noise
            model that does not take samples not observed (the repeats' AR(p)).
        """
        *noise, n_stretches = noise_and_stretches
        if self.n_trials != 1 or not self.noise.takes_missing or n_stretches < 2:
            return None
        x = np.atleast_2d(x)
        pars = self.noise.broadcast(noise, x.shape[0])
        obs = (np.ones((1, self.n_samples), dtype=bool) if self.observed is None
               else np.asarray(self.observed, dtype=bool))
        x3 = self._by_trial(x)
        whole = self.noise.log_likelihood(self._trials, x3, 1.0, pars, obs)[:, 0]
        edges = np.linspace(0, self.n_samples, n_stretches + 1).astype(int)
        out = np.empty((x.shape[0], n_stretches))
        for k in range(n_stretches):
            rest = obs.copy()
            rest[:, edges[k]:edges[k + 1]] = False
            out[:, k] = whole - self.noise.log_likelihood(self._trials, x3, 1.0, pars,
                                                          rest)[:, 0]
        return out


def estimated_states(model: Model) -> tuple:
    """The effects whose states an estimated start estimates, in the kernel's order:
    those whose :meth:`~pmabayes.model.effects.base.Effect.start_state` gives a prior.

    Parameters
    ----------
    model : Model

    Returns
    -------
    tuple of Effect classes
    """
    probe = dict(force_n=1.0, motion_m=1.0, work_j=1.0)
    return tuple(e for e in state_effects(model) if e.start_state(**probe) is not None)


def full_start(model: Model, start: np.ndarray) -> np.ndarray:
    """An estimated start's values ``(batch, n)`` as the simulator takes them: its
    effects' states that are not estimated (their effect gives no
    :meth:`~pmabayes.model.effects.base.Effect.start_state`) put in at 0, at rest.

    Parameters
    ----------
    model : Model
        The model the start is of.
    start : numpy.ndarray
        ``(batch, 3 + k)``: position, velocity, ``z`` offset, then the ``k`` estimated
        states in the kernel's order (:meth:`Likelihood.start_parameters`).

    Returns
    -------
    numpy.ndarray
        ``(batch, 3 + all states)``.
    """
    start = np.atleast_2d(np.asarray(start, dtype=float))
    estimated = [e in estimated_states(model) for e in state_effects(model)]
    if all(estimated):
        return start
    out = np.zeros((start.shape[0], 3 + len(estimated)))
    out[:, :3] = start[:, :3]
    out[:, 3 + np.flatnonzero(estimated)] = start[:, 3:]
    return out


#: Seconds at the start of a record whose samples set the priors of an estimated start
#: (:meth:`Likelihood.start_parameters`).
START_WINDOW_S = 0.05


def _start_priors(lik: Likelihood) -> tuple[Parameter, ...]:
    """The priors of an estimated start (:meth:`Likelihood.start_parameters`)."""
    ds = lik.dataset
    t = ds.time_s - ds.time_s[0]
    y = ds.mean_position_m
    first = np.flatnonzero(np.isfinite(y) & (t <= START_WINDOW_S))
    if first.size < 5:  # a record sampled slowly: its first five samples
        first = np.flatnonzero(np.isfinite(y))[:5]
    # a parabola: mid-loop the motion curves within the window, and a line's intercept
    # and slope would carry that curvature's bias
    design = np.stack([np.ones(first.size), t[first], t[first] ** 2], axis=1)
    coef, *_ = np.linalg.lstsq(design, y[first], rcond=None)
    resid = y[first] - design @ coef
    s2 = float(resid @ resid) / max(first.size - 3, 1)
    se = np.sqrt(np.maximum(np.diag(np.linalg.pinv(design.T @ design)) * s2, 0.0))
    duration = max(float(t[-1]), ds.dt_s)
    sd_x = max(3.0 * se[0], 3.0 * math.sqrt(s2), 1e-3 * lik.motion_m)
    sd_v = max(3.0 * se[1], abs(float(coef[1])), lik.motion_m / duration)
    u = ds.input[np.isfinite(ds.input)]
    swing = float(np.ptp(u)) or float(np.max(np.abs(u))) or 1.0
    sd_z = swing * (lik.model.rig.area_m2 if ds.input_name == "pressure_pa" else 1.0)

    def start(name: str, unit: str, mean: float, sd: float, text: str, latex: str):
        # bounds far out in the prior's tails: finite, so that boxes built from them are
        return Parameter(name, unit, mean, Normal(mean, sd), bounds=(mean - 1e3 * sd,
                                                                    mean + 1e3 * sd),
                         description=f"{text} (an estimated start)", latex=latex)

    return (
        start("x0_m", "m", float(coef[0]), sd_x, "position at the first sample", r"x_0"),
        start("v0_m_s", "m/s", float(coef[1]), sd_v, "velocity at the first sample",
              r"\dot x_0"),
        start("z0_offset_n", "N", 0.0, sd_z, "hysteretic force at the first sample, as an "
              "offset from the balance of forces there", r"\Delta z_0"),
    ) + _effect_start_states(lik.model, ds, sd_z, lik.motion_m)


def _effect_start_states(model, ds, force_n: float, motion_m: float
                         ) -> tuple[Parameter, ...]:
    """The estimated start's parameters of the effects' states, in the kernel's order
    (:func:`pmabayes.model.codegen.state_effects`), each from its effect's
    :meth:`~pmabayes.model.effects.base.Effect.start_state`; a state its effect gives
    no prior is not estimated (:func:`full_start` puts it at 0, at rest)."""
    y = ds.mean_position_m
    f = ds.input[0] * (model.rig.area_m2 if ds.input_name == "pressure_pa" else 1.0)
    with np.errstate(invalid="ignore"):
        step = 0.5 * (f[1:] + f[:-1]) * np.diff(y)
    work = float(np.nansum(np.abs(step)))
    given = (e.start_state(force_n=force_n, motion_m=motion_m, work_j=work)
             for e in state_effects(model))
    return tuple(p for p in given if p is not None)



def span(y: np.ndarray) -> float:
    """Largest minus smallest of the values observed (NaN marks a sample not observed).

    Parameters
    ----------
    y : numpy.ndarray

    Returns
    -------
    float
    """
    return float(np.nanmax(y) - np.nanmin(y))


class JointLikelihood:
    """Several experiments seen as one, for the global search and the quality check.

    Physical parameters are shared, so one parameter array simulates every
    experiment; the outputs are concatenated along time. Each experiment keeps its
    own :class:`Likelihood` (its data, rig, input and noise).

    Parameters
    ----------
    likelihoods : sequence of Likelihood
        One per experiment, with models that share their parameters (same effects
        and fixed values; the rigs may differ).
    names : sequence of str
        The experiments' names.

    Raises
    ------
    LikelihoodError
        If the experiments' models do not share their parameters.
    """

    def __init__(self, likelihoods, names) -> None:
        self.likelihoods = list(likelihoods)
        self.names = list(names)
        first = self.likelihoods[0].model

        def physics(model: Model) -> list[str]:  # a rig's own values may differ
            return [p.name for p in model.parameters if not model.is_rig_parameter(p.name)]

        for lik in self.likelihoods[1:]:
            if physics(lik.model) != physics(first):
                raise LikelihoodError(
                    f"{lik.dataset.source or 'an experiment'}: its model has parameters "
                    f"{physics(lik.model)}, the first experiment's {physics(first)}; "
                    "experiments of one fit share the model's effects")
        self.model = first
        self.dataset = self.likelihoods[0].dataset
        self.substeps = self.likelihoods[0].substeps
        self.sizes = [lik.n_outputs for lik in self.likelihoods]
        self._edges = np.cumsum([0, *self.sizes])
        self.n_samples = self.n_outputs = int(self._edges[-1])
        self.y_mean = np.concatenate([lik.y_mean for lik in self.likelihoods])
        self.input = np.concatenate([lik.input for lik in self.likelihoods])
        self.motions_m = np.array([span(lik.y_mean) for lik in self.likelihoods])

    def split(self, x: np.ndarray) -> list[np.ndarray]:
        """Concatenated outputs ``(batch, n_samples)`` cut into each experiment's.

        Parameters
        ----------
        x : numpy.ndarray
            ``(batch, n_samples)`` or ``(n_samples,)``.

        Returns
        -------
        list of numpy.ndarray
        """
        x = np.atleast_2d(x)
        return [x[:, a:b] for a, b in zip(self._edges[:-1], self._edges[1:], strict=True)]

    def simulate(self, theta: np.ndarray, starts=None) -> np.ndarray:
        """Every experiment's model positions, concatenated: ``(batch, n_outputs)``
        (``starts``: each experiment's estimated start, or None)."""
        starts = starts or [None] * len(self.likelihoods)
        return np.concatenate([lik.simulate(theta, start) for lik, start in
                               zip(self.likelihoods, starts, strict=True)], axis=1)

    def rms_costs(self, x: np.ndarray) -> np.ndarray:
        """Each experiment's RMS cost, ``(batch, n_experiments)``."""
        return np.stack([lik.rms_cost(xe) for lik, xe in
                         zip(self.likelihoods, self.split(x), strict=True)], axis=1)

    def rms_cost(self, x: np.ndarray) -> np.ndarray:
        """The combined cost: the experiments' RMS costs, each relative to its motion.

        ``mean_motion * sqrt(mean_e (rms_e / motion_e)^2)``, in metres: every
        experiment weighs the same whatever its length or amplitude, and with one
        experiment it is the paper's RMS cost.

        Parameters
        ----------
        x : numpy.ndarray
            Concatenated model positions ``(batch, n_samples)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        rel = self.rms_costs(x) / self.motions_m
        return self.motions_m.mean() * np.sqrt(np.mean(rel * rel, axis=1))

    def rms_cost_parts(self, xs: list[np.ndarray]) -> np.ndarray:
        """:meth:`rms_cost` of the experiments' outputs given apart, to the bit: the
        global search's cost without concatenating (and transposing) every member's
        outputs of records with samples not observed (a lab's clock with gaps).

        Parameters
        ----------
        xs : list of numpy.ndarray
            Each experiment's model positions ``(batch, n_outputs)``.

        Returns
        -------
        numpy.ndarray
            ``(batch,)``.
        """
        # the masked route reads any layout alike; the unmasked one sums in an order
        # that follows the layout, so it is given the concatenation's parts as before
        masked = [lik.observed is not None or lik.own_inputs for lik in self.likelihoods]
        if not all(masked):
            whole = self.split(np.concatenate(xs, axis=1))
            xs = [xe if m else w for xe, w, m in zip(xs, whole, masked, strict=True)]
        rel = np.stack([lik.rms_cost(xe) for lik, xe in zip(self.likelihoods, xs, strict=True)],
                       axis=1) / self.motions_m
        return self.motions_m.mean() * np.sqrt(np.mean(rel * rel, axis=1))


# ---------------------------------------------------------------------------------
# a higher-order noise model: AR(p) from the repeats

