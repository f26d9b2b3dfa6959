"""What the criticism sees of a lab's record: the trial mean at the samples counted, the
model's trial mean beside it, and series with gaps bridged for a spectrum.

A lab's record may have samples not observed (gaps in its DAQ's clock, a declared
warm-up), trials with their own measured inputs, and a start that is estimated. The
likelihood takes them exactly (:class:`pmabayes.inference.likelihood.Likelihood`); the
criticism takes the same view of them:

* **the residual** is the trial mean minus the model's trial mean (each trial's model on
  its own input, averaged as the trials are), NaN where no trial is counted: a sample
  not observed is never invented (:func:`residual`);
* **the model** is simulated from the experiment's estimated start where it has one, on
  each trial's own input where the trials have their own (:func:`simulate_states`);
* **spectra** (errors per band) take series with gaps bridged by straight lines between
  the samples observed either side, for the spectrum only (:func:`bridged`); each
  series' spectrum is scaled to the mean square of its samples observed, so the bands
  still add up to the error over those samples alone.

Complete records with shared inputs and known starts pass through unchanged, to the bit.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pmabayes.data import Dataset
from pmabayes.inference.likelihood import Likelihood, full_start
from pmabayes.model.model import Model
from pmabayes.model.simulator import Simulation, simulate_dataset

__all__ = ["counted_samples", "trial_weights", "trials_mean", "model_mean", "observed_mean",
           "residual", "simulate_states", "bridged", "share_inside", "shared_input",
           "mean_of_observed"]


def counted_samples(likelihood: Likelihood) -> np.ndarray:
    """Where the trial mean is data: some trial counted there, ``(n_samples,)``.

    Parameters
    ----------
    likelihood : Likelihood
        The experiment.

    Returns
    -------
    numpy.ndarray
        Boolean; all True for a complete record without a warm-up.
    """
    if likelihood.observed is None:
        return np.ones(likelihood.n_samples, dtype=bool)
    return likelihood.observed.any(axis=0)


def trial_weights(seen: np.ndarray) -> np.ndarray | None:
    """Each trial's weight in the trial mean at each sample ``(n_trials, n_samples)``.

    Parameters
    ----------
    seen : numpy.ndarray
        Boolean ``(n_trials, n_samples)``: where each trial is counted.

    Returns
    -------
    numpy.ndarray or None
        The trials counted at a sample, equally (all of them where none is); None where
        the trials are counted at the same samples (the plain mean over the trials).
    """
    if bool(np.all(seen == seen[0])):
        return None
    n = seen.sum(axis=0)
    return np.where(n > 0, seen / np.maximum(n, 1), 1.0 / seen.shape[0])


def trials_mean(dataset: Dataset, x: np.ndarray) -> np.ndarray:
    """Per-trial model outputs ``(batch, n_trials, n_samples)`` averaged as the trial mean
    averages the data (over the trials counted at each sample): ``(batch, n_samples)``.

    Parameters
    ----------
    dataset : Dataset
        The trials.
    x : numpy.ndarray
        Each trial's model output.

    Returns
    -------
    numpy.ndarray
    """
    w = trial_weights(dataset.counted)
    return x.mean(axis=1) if w is None else np.einsum("brn,rn->bn", x, w)


def model_mean(likelihood: Likelihood, x: np.ndarray) -> np.ndarray:
    """The model's trial mean ``(batch, n_samples)`` of outputs ``(batch, n_outputs)``.

    With a shared input the model's output is the trial mean's (returned as it is).
    With trials on their own inputs, each trial's output averaged as the trial mean
    averages the data (:func:`trials_mean`).

    Parameters
    ----------
    likelihood : Likelihood
        The experiment.
    x : numpy.ndarray
        :meth:`~pmabayes.inference.likelihood.Likelihood.simulate`'s output.

    Returns
    -------
    numpy.ndarray
    """
    x = np.atleast_2d(x)
    if not likelihood.own_inputs:
        return x
    return trials_mean(likelihood.dataset,
                       x.reshape(x.shape[0], likelihood.n_trials, likelihood.n_samples))


def observed_mean(dataset: Dataset) -> np.ndarray:
    """The measured trial mean ``(n_samples,)``, NaN where no trial is counted.

    Parameters
    ----------
    dataset : Dataset
        The trials.

    Returns
    -------
    numpy.ndarray
    """
    counted = dataset.counted
    if counted.all():
        return dataset.mean_position_m
    return np.where(counted.any(axis=0), dataset.mean_position_m, np.nan)


def residual(likelihood: Likelihood, x_mean: np.ndarray) -> np.ndarray:
    """The trial mean minus the model's, NaN where no trial is counted.

    Parameters
    ----------
    likelihood : Likelihood
        The experiment.
    x_mean : numpy.ndarray
        The model's trial mean ``(n_samples,)`` (:func:`model_mean`).

    Returns
    -------
    numpy.ndarray
        ``(n_samples,)``.
    """
    if likelihood.observed is None:
        return likelihood.y_mean - np.asarray(x_mean, dtype=float).reshape(-1)
    return observed_mean(likelihood.dataset) - np.asarray(x_mean, dtype=float).reshape(-1)


def simulate_states(likelihood: Likelihood, model: Model, values: dict,
                    start: np.ndarray | None, substeps: int
                    ) -> tuple[Simulation, np.ndarray | None]:
    """The model's states at a point, on the experiment's inputs and from its start.

    Parameters
    ----------
    likelihood : Likelihood
        The experiment (its data set, whether its trials have their own inputs).
    model : Model
        The model to simulate (the likelihood's, or one with an effect added).
    values : dict
        Its parameters' values.
    start : numpy.ndarray or None
        The experiment's estimated start of ``model`` ``(3 + k,)`` (``x0_m``,
        ``v0_m_s``, ``z0_offset_n``, the effects' states it estimates:
        :meth:`~pmabayes.inference.likelihood.Likelihood.start_parameters`), None for a
        declared one.
    substeps : int
        Simulator substeps per sample.

    Returns
    -------
    simulation : Simulation
        A batch of one: the model's trial mean of every state (the model itself where
        the trials share their input).
    trials : numpy.ndarray or None
        Each trial's model position ``(n_trials, n_samples)`` where the trials have
        their own inputs (for the noise floor of their residuals), else None.
    """
    init = (None if start is None
            else full_start(model, np.asarray(start, dtype=float).reshape(1, -1)))
    sim = simulate_dataset(model, values, likelihood.dataset, substeps=substeps, states=True,
                           per_trial=likelihood.own_inputs, initial_values=init)
    if not likelihood.own_inputs:
        return sim, None
    w = trial_weights(likelihood.dataset.counted)

    def mean(a: np.ndarray) -> np.ndarray:
        return (a.mean(axis=0) if w is None else np.sum(a * w, axis=0))[None, :]

    fields = {f.name: mean(getattr(sim, f.name)) for f in dataclasses.fields(sim)
              if f.name != "time_s"}
    return dataclasses.replace(sim, **fields), np.array(sim.position_m)


def bridged(series: np.ndarray) -> np.ndarray:
    """Series with their NaN samples bridged by straight lines, for a spectrum only.

    Each row's samples not observed (NaN) take the line between the samples observed
    either side (the nearest one's value before the first or after the last); the rows
    observed everywhere are returned as they are.

    Parameters
    ----------
    series : numpy.ndarray
        ``(n_samples,)`` or ``(n_series, n_samples)``.

    Returns
    -------
    numpy.ndarray
        Same shape, finite wherever a row has an observed sample.
    """
    a = np.array(series, dtype=float)
    rows = a.reshape(-1, a.shape[-1])
    k = np.arange(rows.shape[1])
    for row in rows:
        seen = np.isfinite(row)
        if seen.all() or not seen.any():
            continue
        row[~seen] = np.interp(k[~seen], k[seen], row[seen])
    return a


def share_inside(data: np.ndarray, low: np.ndarray, high: np.ndarray) -> float:
    """Fraction of the measured samples inside a band; a sample not observed (NaN) is
    not measured and does not count.

    Parameters
    ----------
    data : numpy.ndarray
        Measured positions, NaN where not observed.
    low, high : numpy.ndarray
        The band's edges, broadcast against ``data``.

    Returns
    -------
    float
    """
    seen = np.isfinite(data)
    return float(np.mean(((data >= low) & (data <= high))[seen]))


def shared_input(dataset: Dataset) -> np.ndarray:
    """The trials' input as one series: the shared one, or the mean of their own inputs
    (what a linear model's trial mean responds to; the command whose rate the whitened
    residual is correlated with).

    Parameters
    ----------
    dataset : Dataset
        Its trials share one input or each has its own.

    Returns
    -------
    numpy.ndarray
        ``(n_samples,)``.
    """
    u = np.asarray(dataset.input, dtype=float)
    return u[0] if bool(np.all(u == u[0])) else u.mean(axis=0)


def mean_of_observed(rows: np.ndarray) -> np.ndarray:
    """The mean over rows (trials) of the values observed, NaN where none is.

    Parameters
    ----------
    rows : numpy.ndarray
        ``(n_rows, n_samples)``, NaN where not observed.

    Returns
    -------
    numpy.ndarray
        ``(n_samples,)``; the plain mean over the rows where every value is observed.
    """
    seen = np.isfinite(rows)
    if seen.all():
        return rows.mean(axis=0)
    n = seen.sum(axis=0)
    return np.where(n > 0, np.where(seen, rows, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan)
