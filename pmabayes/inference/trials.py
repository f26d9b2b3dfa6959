"""Are the repeated trials exchangeable? Drift with trial order and outlier trials.

Stage 4 (beside the likelihood; it needs only the data): the noise model learns
the noise from the spread between repeated trials, which is right only when the
trials are repetitions of one experiment, i.e. exchangeable: their order carries
no information and none of them is special. A rig that warms up (an offset
growing with trial index), a muscle that softens over its first cycles
(Mullins-like), or a trial bumped by a hand are not noise, and they would be
taken for it. :func:`check_trials` tests this before the noise is estimated:

* **drift with trial order**: two features of each trial's deviation from the
  trial mean, its offset (time average) and its score on the first principal
  direction of the deviations, are regressed on the trial index (their
  correlation with it). The null is exact: under exchangeability every order of
  the trials is equally likely, so the p-value is a permutation test, whatever
  the noise. Where the change happens (the peak of the CUSUM) names the trials;
* **outlier trial**: each trial's RMS deviation from the mean of the others,
  over the mean of the others' (the largest of these ratios). Its null comes
  from surrogate trials of Gaussian noise with the trials' own spectrum (the
  median over trials of the periodograms of their leave-one-out deviations, so
  that one odd trial does not set it), which calibrates the threshold for
  slow, correlated disturbances as well as for white noise.

Each test runs at level ``level`` (Bonferroni over the three). A failed check
says which trials and by how much (µm, and as a multiple of the typical
deviation), warns with :class:`TrialWarning`, and drops nothing: dropping is
the user's call, through :func:`exclude_trials` (``--exclude-trials`` on the
command line).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmabayes.data import DataError, Dataset, DataWarning

__all__ = ["TrialWarning", "TrialFinding", "TrialCheck", "check_trials", "exclude_trials",
           "keep_trials", "parse_trial_ids"]

#: Level of each of the three tests (offset drift, shape drift, outlier).
LEVEL = 0.01


class TrialWarning(DataWarning):
    """Repeated trials that are not exchangeable: a drift with trial order or an outlier.

    The message names the trials, the size of the difference and the fix
    (``--exclude-trials``, or record the trials again after warming the rig up).
    """


@dataclass(frozen=True)
class TrialFinding:
    """One departure from exchangeability found by :func:`check_trials`.

    Parameters
    ----------
    kind : str
        ``"offset drift"``, ``"shape drift"`` or ``"outlier"``.
    trial_ids : tuple of int
        The trials concerned (ids, not positions).
    size_m : float
        How far they are from the others, RMS in m.
    multiple : float
        ``size_m`` over the typical deviation of a trial from the others.
    p_value : float
        Of the test that found it.
    text : str
        The finding in a sentence.
    """

    kind: str
    trial_ids: tuple[int, ...]
    size_m: float
    multiple: float
    p_value: float
    text: str


@dataclass(frozen=True)
class TrialCheck:
    """Verdict of :func:`check_trials`.

    Parameters
    ----------
    n_trials : int
        Trials checked.
    typical_m : float
        Median over trials of the RMS deviation of a trial from the mean of the
        others.
    deviation_m : dict
        Trial id to that RMS deviation.
    p_values : dict
        Test name (``"offset drift"``, ``"shape drift"``, ``"outlier"``) to its
        p-value (None with fewer than 3 trials: no test).
    findings : list of TrialFinding
        The tests that failed.
    level : float
        Level of each test.
    """

    n_trials: int
    typical_m: float
    deviation_m: dict
    p_values: dict
    findings: list = field(default_factory=list)
    level: float = LEVEL

    @property
    def exchangeable(self) -> bool:
        """True when no test failed."""
        return not self.findings

    @property
    def flagged(self) -> tuple[int, ...]:
        """Ids of the trials named by any finding, sorted."""
        return tuple(sorted({t for f in self.findings for t in f.trial_ids}))

    def summary(self) -> str:
        """The verdict in one line, for a report or a terminal."""
        if self.n_trials < 3:
            return f"Trials: {self.n_trials}, too few to test for drift or outliers."
        if self.exchangeable:
            return (f"Trials: {self.n_trials} exchangeable (no drift with trial order, no "
                    f"outlier at level {self.level:g} each; typical deviation "
                    f"{self.typical_m * 1e6:.3g} µm).")
        return "Trials NOT exchangeable: " + " ".join(f.text for f in self.findings)

    def to_dict(self) -> dict:
        """JSON-ready values."""
        return {"n_trials": self.n_trials, "exchangeable": self.exchangeable,
                "typical_m": self.typical_m,
                "deviation_m": {str(k): v for k, v in self.deviation_m.items()},
                "p_values": self.p_values, "level": self.level,
                "findings": [{"kind": f.kind, "trial_ids": list(f.trial_ids),
                              "size_m": f.size_m, "multiple": f.multiple,
                              "p_value": f.p_value, "text": f.text} for f in self.findings]}


def _cusum(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Largest standardised CUSUM of each row of ``s`` (..., R), and where it peaks."""
    c = np.cumsum(s - s.mean(axis=-1, keepdims=True), axis=-1)[..., :-1]
    a = np.abs(c)
    k = np.argmax(a, axis=-1)
    scale = s.std(axis=-1) * math.sqrt(s.shape[-1])
    return np.take_along_axis(a, k[..., None], -1)[..., 0] / np.maximum(scale, 1e-300), k + 1


def _trend(s: np.ndarray) -> np.ndarray:
    """``|correlation|`` of each row of ``s`` (..., R) with the trial index."""
    i = np.arange(s.shape[-1]) - (s.shape[-1] - 1) / 2.0
    c = s - s.mean(axis=-1, keepdims=True)
    return np.abs(c @ i) / np.maximum(np.sqrt(np.sum(c * c, axis=-1) * (i @ i)), 1e-300)


def _permutation_p(s: np.ndarray, rng: np.random.Generator, n_perm: int) -> tuple[float, int]:
    """Permutation p-value of the trend of ``s`` with trial index, and the CUSUM's split."""
    perms = np.argsort(rng.random((n_perm, s.size)), axis=1)
    null = _trend(s[perms])
    p = float((1 + np.sum(null >= _trend(s) - 1e-12)) / (1 + n_perm))
    return p, int(_cusum(s)[1])


def _outlier_ratio(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each trial's mean-square deviation from the others' mean, over the others' mean of it.

    ``y`` is ``(..., R, n)``; returns the ratios and the mean squares, ``(..., R)``.
    """
    r = y.shape[-2]
    loo = (y.sum(axis=-2, keepdims=True) - y) / (r - 1)
    ms = np.mean((y - loo) ** 2, axis=-1)
    others = (ms.sum(axis=-1, keepdims=True) - ms) / (r - 1)
    return ms / np.maximum(others, 1e-300), ms


def check_trials(dataset: Dataset, *, level: float = LEVEL, n_null: int = 200,
                 seed: int | np.random.Generator = 0, warn: bool = False) -> TrialCheck:
    """Test that repeated trials are exchangeable: no drift with trial order, no outlier.

    Parameters
    ----------
    dataset : Dataset
        The trials.
    level : float
        Level of each of the three tests.
    n_null : int
        Permutations, and surrogate data sets, of the null distributions.
    seed : int or numpy.random.Generator
        For the permutations and the surrogates.
    warn : bool
        Warn with :class:`TrialWarning` when a test fails (as the fit does).

    Returns
    -------
    TrialCheck
        With no test (p-values None) for fewer than 3 trials. With samples not
        observed, only the samples every trial observed are compared.

    Raises
    ------
    ValueError
        If ``level`` is not in (0, 1) or ``n_null`` is below 20.

    Examples
    --------
    The ten repeats of the bundled lab-like chirps (``data/`` of a checkout) are
    exchangeable:

    >>> from pmabayes.data import load
    >>> from pmabayes.inference.trials import check_trials
    >>> check = check_trials(load("data/pma_chirp_lab.csv"))
    >>> check.findings
    []
    >>> sorted(check.p_values)
    ['offset drift', 'outlier', 'shape drift']
    """
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1); got {level!r}")
    if int(n_null) < 20:
        raise ValueError(f"n_null must be at least 20 (the null distributions); got {n_null!r}")
    check = _check_trials(dataset, level, n_null, seed)
    if warn and not check.exchangeable:
        where = dataset.source or "the data set"
        warnings.warn(f"{where}: {check.summary()} The noise is learnt from the spread "
                      "between the trials and would take this for noise. If these trials are "
                      "not repetitions of one experiment, leave them out with --exclude-trials "
                      f"{','.join(map(str, check.flagged))} (exclude_trials in the API), or "
                      "record the trials again once the rig has settled.", TrialWarning,
                      stacklevel=3)
    return check


def _check_trials(dataset: Dataset, level: float, n_null: int,
                  seed: int | np.random.Generator) -> TrialCheck:
    rng = np.random.default_rng(seed)
    y = np.asarray(dataset.position_m, dtype=float)
    if dataset.n_missing:  # the samples every trial observed: deviations need them all
        y = y[:, dataset.observed.all(axis=0)]
    ids = [int(i) for i in dataset.trial_ids]
    r, n = y.shape
    if r < 2:
        return TrialCheck(n_trials=r, typical_m=math.nan, deviation_m={},
                          p_values={}, level=level)
    ratio, ms = _outlier_ratio(y)
    dev = np.sqrt(ms)
    typical = float(np.median(dev))
    deviation = dict(zip(ids, (float(v) for v in dev), strict=True))
    if r < 3:
        return TrialCheck(n_trials=r, typical_m=typical, deviation_m=deviation,
                          p_values={"offset drift": None, "shape drift": None,
                                    "outlier": None}, level=level)
    d = y - y.mean(axis=0)
    findings = []
    p_values = {}

    # drift: offset, and the score on the first principal direction of the deviations
    offset = d.mean(axis=1)
    shape = d - offset[:, None]
    w, v = np.linalg.eigh(shape @ shape.T)  # R x R: cheaper than the SVD of R x n
    score = v[:, -1] * math.sqrt(max(w[-1], 0.0) / n)  # RMS-equivalent, in m
    for kind, s in (("offset drift", offset), ("shape drift", score)):
        p, split = _permutation_p(s, rng, n_null)
        p_values[kind] = p
        if p < level:
            early, late = s[:split].mean(), s[split:].mean()
            size = float(abs(late - early))
            side = ids[:split] if split <= r - split else ids[split:]
            what = "offset" if kind == "offset drift" else "shape"
            findings.append(TrialFinding(
                kind=kind, trial_ids=tuple(side), size_m=size, multiple=size / typical,
                p_value=p,
                text=(f"the trials drift with trial order ({what}, permutation p = {p:.2g}): "
                      f"trials {_span(ids[:split])} and trials {_span(ids[split:])} differ by "
                      f"{size * 1e6:.3g} µm RMS, {size / typical:.2g}x the typical deviation "
                      f"of a trial ({typical * 1e6:.3g} µm).")))

    # outlier: surrogate trials with the deviations' own (robust) spectrum
    loo = (y.sum(axis=0) - y) / (r - 1)
    periodograms = np.abs(np.fft.rfft(y - loo, axis=1)) ** 2
    spectrum = np.median(periodograms, axis=0)  # one odd trial does not set it
    null = np.empty(n_null)
    for k in range(n_null):
        z = rng.standard_normal((r, spectrum.size)) + 1j * rng.standard_normal((r, spectrum.size))
        sur = np.fft.irfft(z * np.sqrt(spectrum), n=n, axis=1)
        null[k] = _outlier_ratio(sur)[0].max()
    worst = float(ratio.max())
    p = float((1 + np.sum(null >= worst)) / (1 + n_null))
    p_values["outlier"] = p
    if p < level:
        threshold = float(np.quantile(null, 1.0 - level))
        bad = [i for i, q in zip(ids, ratio, strict=True) if q > threshold]
        for i in bad:
            size = deviation[i]
            findings.append(TrialFinding(
                kind="outlier", trial_ids=(i,), size_m=size, multiple=size / typical, p_value=p,
                text=(f"trial {i} is an outlier (p = {p:.2g}): it deviates from the mean of the "
                      f"others by {size * 1e6:.3g} µm RMS, {size / typical:.2g}x the typical "
                      f"deviation ({typical * 1e6:.3g} µm).")))
    return TrialCheck(n_trials=r, typical_m=typical, deviation_m=deviation, p_values=p_values,
                      findings=findings, level=level)


def _span(ids: list[int]) -> str:
    return str(ids[0]) if len(ids) == 1 else f"{ids[0]}-{ids[-1]}"


def exclude_trials(dataset: Dataset, ids: Iterable[int], *, min_trials: int = 2) -> Dataset:
    """The data set without the trials of the given ids (never silently: the caller asks).

    Parameters
    ----------
    dataset : Dataset
        The trials.
    ids : iterable of int
        Trial ids (as in the file's ``trial`` column, not positions) to leave out.
    min_trials : int
        Fewest trials that must remain (2: the noise is learned from repeats).

    Returns
    -------
    Dataset
        The other trials, in their order.

    Raises
    ------
    DataError
        For an id the data do not hold, or when fewer than ``min_trials`` would
        remain.

    Examples
    --------
    Hold trials 8 and 9 out of a fit (``pmabayes.fit(data, trials=...)`` does the same
    and records it in the fit file):

    >>> from pmabayes.data import load
    >>> from pmabayes.inference.trials import exclude_trials
    >>> data = load("data/pma_chirp_lab.csv")
    >>> exclude_trials(data, [8, 9]).trial_ids
    array([0, 1, 2, 3, 4, 5, 6, 7])
    >>> exclude_trials(data, [10])
    Traceback (most recent call last):
    ...
    pmabayes.data.dataset.DataError: ...
    """
    where = dataset.source or "the data set"
    ids = [int(i) for i in ids]
    have = [int(i) for i in dataset.trial_ids]
    unknown = [i for i in ids if i not in have]
    if unknown:
        raise DataError(f"{where}: no trial with id {', '.join(map(str, unknown))} to exclude; "
                        f"the trial ids are {have}")
    keep = [k for k, i in enumerate(have) if i not in ids]
    if len(keep) < min_trials:
        raise DataError(f"{where}: excluding trials {sorted(set(ids))} leaves {len(keep)} of "
                        f"{len(have)}; at least {min_trials} repeated trials are needed to "
                        "tell the model's error from the noise. Exclude fewer trials.")
    out = dataset.select_trials(keep)
    if len(keep) < len(have):  # the next command (diagnose, validate) must choose them too
        out.metadata["selected_trials"] = [have[k] for k in keep]
    return out


def keep_trials(datasets: Dataset | Sequence[Dataset], ids: Iterable[int], *,
                min_trials: int = 1) -> list[Dataset]:
    """The data sets with only the trials of the given ids: the others left out through
    :func:`exclude_trials` (``trials=`` of :func:`pmabayes.fit` and
    :func:`pmabayes.validate`).

    Parameters
    ----------
    datasets : Dataset or sequence of Dataset
        One file's data: one data set, or the segments of one record (trial ids
        belong to a file).
    ids : iterable of int
        Trial ids (as in the file's ``trial`` column) to keep.
    min_trials : int
        Fewest trials to keep.

    Returns
    -------
    list of Dataset
        Each with the trials asked for, in the file's order.

    Raises
    ------
    DataError
        For data sets of several files, an id a data set does not hold, or no id.
    """
    datasets = [datasets] if isinstance(datasets, Dataset) else list(datasets)
    ids = [int(i) for i in ids]
    files = list(dict.fromkeys(d.source_file for d in datasets))
    if len(files) > 1 or (len(datasets) > 1 and files == [None]):
        raise DataError(
            f"trials={ids}: trial ids belong to one data file, but the data come from "
            f"{len(datasets)} ({', '.join(str(f) for f in files[:4])}); select the trials of "
            "each file alone (pmabayes.inference.keep_trials) and pass the data sets")
    out = []
    for d in datasets:
        have = [int(i) for i in d.trial_ids]
        unknown = [i for i in ids if i not in have]
        if unknown or not ids:
            raise DataError(f"{d.source or 'the data set'}: trials={ids}: no trial with id "
                            f"{', '.join(map(str, unknown)) or '(none given)'}; the trial ids "
                            f"are {have}")
        out.append(exclude_trials(d, [i for i in have if i not in ids], min_trials=min_trials))
    return out


def parse_trial_ids(text: str) -> list[int]:
    """Trial ids from ``"3,7"`` (for ``--exclude-trials``).

    Parameters
    ----------
    text : str
        Comma-separated integers.

    Returns
    -------
    list of int

    Raises
    ------
    ValueError
        For anything that is not an integer.
    """
    out = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            out.append(int(part))
        except ValueError:
            raise ValueError(f"trial id {part!r} is not an integer; give ids like 3,7") from None
    return out
