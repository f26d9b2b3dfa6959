"""The experiments a design chooses from: their families, the rig's input range, the
dead loads and the duration budget.

An :class:`Experiment` is one input signal on the rig, in SI (Pa, or N on a force rig),
sampled at the data's rate for the budget's duration, perhaps with another dead load
hung in place of the first data set's (:func:`loaded_mass_kg`). Four families make the
candidates (:func:`candidate_experiments`):

``chirp``
    ``offset - amplitude cos(2 pi (f0 t + (f1 - f0) t^2 / (2 T))``: a sweep of a band.
``steps``
    Levels held for ``hold_s`` each, in a random order (steps and holds).
``noise``
    Band-limited noise: random phases over ``f0``..``f1``, scaled to ``amplitude`` peak.
``sine``
    ``offset - amplitude cos(2 pi f0 t)``.

Each starts at its lowest point where it can (a chirp, a sine), so that the record starts
at rest under its first sample (the simulator's ``"rest"``), and stays inside the input
range. Two more are always scored: ``repeat`` (the first data set's first trial's input,
on the budget's length) and ``default_chirp`` (0.1 to 3 Hz over the whole input range),
the comparisons a design must beat.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["DesignError", "Experiment", "FAMILIES", "input_range", "candidate_experiments",
           "MIN_SAMPLES", "dead_load_kg", "loaded_mass_kg"]

#: the families a design draws candidates from
FAMILIES = ("chirp", "steps", "noise", "sine")

#: an experiment shorter than this many samples cannot be scored: the design refuses it
MIN_SAMPLES = 20


class DesignError(ValueError):
    """A design cannot be made as asked; the message names the input and the fix."""


@dataclass(frozen=True)
class Experiment:
    """One candidate experiment: an input signal on the rig.

    Parameters
    ----------
    family : str
        ``"chirp"``, ``"steps"``, ``"noise"``, ``"sine"``, ``"repeat"`` or
        ``"default_chirp"``.
    duration_s : float
        Its length.
    sample_rate_hz : float
        Its sampling rate (the data's).
    settings : dict
        The family's settings in SI (``f0_hz``, ``f1_hz``, ``amplitude``, ``offset``,
        ``levels``, ``hold_s``, ``seed``), or for ``repeat`` the input itself
        (``signal``).
    load_kg : float or None
        The dead load hung on the rig in this experiment, kg (0: none), in place of the
        first data set's (:func:`loaded_mass_kg`); None: the rig as the first data set
        has it.
    """

    family: str
    duration_s: float
    sample_rate_hz: float
    settings: dict = field(default_factory=dict)
    load_kg: float | None = None

    @property
    def time_s(self) -> np.ndarray:
        """Sample times from 0, ``round(duration * rate)`` of them."""
        return np.arange(int(round(self.duration_s * self.sample_rate_hz))) / self.sample_rate_hz

    def input(self) -> np.ndarray:
        """The input signal in SI, ``(n_samples,)``."""
        t = self.time_s
        s = self.settings
        if self.family in ("chirp", "default_chirp"):
            rate = (s["f1_hz"] - s["f0_hz"]) / (2.0 * self.duration_s)
            phase = s["f0_hz"] * t + rate * t**2
            return s["offset"] - s["amplitude"] * np.cos(2.0 * np.pi * phase)
        if self.family == "sine":
            return s["offset"] - s["amplitude"] * np.cos(2.0 * np.pi * s["f0_hz"] * t)
        if self.family == "steps":
            levels = np.asarray(s["levels"], dtype=float)
            k = np.minimum((t / s["hold_s"]).astype(int), levels.size - 1)
            return levels[k]
        if self.family == "noise":
            return _band_noise(t.size, self.sample_rate_hz, s["f0_hz"], s["f1_hz"],
                               s["seed"]) * s["amplitude"] + s["offset"]
        if self.family == "repeat":
            u = np.asarray(s["signal"], dtype=float)
            n = t.size
            # the budget's length: cut, or the last sample held (said in the label)
            return u[:n] if u.size >= n else np.concatenate([u, np.full(n - u.size, u[-1])])
        raise DesignError(f"unknown experiment family {self.family!r}; the families are "
                          f"{', '.join(FAMILIES)}")

    def label(self) -> str:
        """The experiment in a few words, in SI."""
        s = self.settings
        load = "" if self.load_kg is None else f", {self.load_kg:g} kg dead load"
        if self.family == "repeat":
            return f"the first experiment's input again ({self.duration_s:g} s){load}"
        if self.family in ("chirp", "default_chirp", "noise"):
            what = {"chirp": "chirp", "default_chirp": "default chirp",
                    "noise": "band-limited noise"}[self.family]
            return (f"{what} {s['f0_hz']:.3g}-{s['f1_hz']:.3g} Hz, {s['offset']:.4g} "
                    f"+- {s['amplitude']:.4g} ({self.duration_s:g} s){load}")
        if self.family == "sine":
            return (f"sine {s['f0_hz']:.3g} Hz, {s['offset']:.4g} +- {s['amplitude']:.4g} "
                    f"({self.duration_s:g} s){load}")
        return (f"{len(s['levels'])} steps held {s['hold_s']:.3g} s each, levels "
                f"{min(s['levels']):.4g} to {max(s['levels']):.4g} ({self.duration_s:g} s)"
                f"{load}")

    def to_dict(self) -> dict:
        """JSON-ready: family, duration, rate, load and settings (a repeat's signal left
        out: it is the first data set's)."""
        settings = {k: v for k, v in self.settings.items() if k != "signal"}
        return {"family": self.family, "label": self.label(), "duration_s": self.duration_s,
                "sample_rate_hz": self.sample_rate_hz, "load_kg": self.load_kg,
                "settings": settings}


def dead_load_kg(dataset) -> float | None:
    """The dead load a data set was recorded with: its sidecar's ``"conditions":
    {"load_kg": ...}``, kg; None where it declares none.

    Parameters
    ----------
    dataset : Dataset
        A data set.

    Returns
    -------
    float or None
    """
    from pmabayes.data.dataset import experiment_conditions

    return experiment_conditions(dataset.metadata,
                                 str(dataset.source or "the data")).get("load_kg")


def loaded_mass_kg(moving_mass_kg: float, first_load_kg: float, load_kg: float | None
                   ) -> float:
    """The moving mass of the rig with ``load_kg`` hung in place of the first data set's
    dead load.

    A rig's ``moving_mass_kg`` is everything that moves with the muscle's free end, its
    dead load included; a load from ``--loads`` is the one hung in the next experiment
    (the lab's weights, as the first data set declares its own in ``"conditions"``), so
    it replaces the first one: ``moving_mass_kg - first_load_kg + load_kg``.

    Parameters
    ----------
    moving_mass_kg : float
        The first data set's rig's moving mass.
    first_load_kg : float
        Its declared dead load (:func:`dead_load_kg`).
    load_kg : float or None
        The next experiment's dead load; None: the first one's.

    Returns
    -------
    float

    Examples
    --------
    The 100 g file of a muscle whose rig's moving mass is its load (the muscle's own
    mass neglected), and the 300 g weight hung instead:

    >>> loaded_mass_kg(0.1, 0.1, 0.3)
    0.3
    """
    if load_kg is None:
        return float(moving_mass_kg)
    return float(moving_mass_kg) - float(first_load_kg) + float(load_kg)


def _band_noise(n: int, rate_hz: float, f0_hz: float, f1_hz: float, seed: int) -> np.ndarray:
    """Noise of unit peak whose spectrum is flat over ``f0``..``f1`` and nothing else: random
    phases on the FFT's bins in the band (at least one bin)."""
    rng = np.random.default_rng(seed)
    freqs = np.fft.rfftfreq(n, 1.0 / rate_hz)
    band = (freqs >= f0_hz) & (freqs <= f1_hz) & (freqs > 0)
    if not band.any():  # a band narrower than a bin: its nearest bin
        band[max(1, int(np.argmin(np.abs(freqs - 0.5 * (f0_hz + f1_hz)))))] = True
    spectrum = np.zeros(freqs.size, dtype=complex)
    spectrum[band] = np.exp(2j * np.pi * rng.uniform(size=int(band.sum())))
    u = np.fft.irfft(spectrum, n)
    return u / np.max(np.abs(u))


def input_range(datasets: Sequence, given: tuple[float, float] | None,
                declared: tuple[float, float] | None = None) -> tuple[float, float]:
    """The input range the experiments stay in, in SI.

    Parameters
    ----------
    datasets : sequence of Dataset
        The data so far (named in the messages).
    given : (float, float) or None
        The range asked for (``--input-range``), in SI.
    declared : (float, float) or None
        The rig's own declared range, where it declares one.

    Returns
    -------
    (float, float)
        ``given`` where it is inside ``declared``; ``declared`` where nothing is given.

    Raises
    ------
    DesignError
        Where neither is known (pmabayes never guesses how hard a rig may be driven), a
        range is empty, or ``given`` reaches beyond ``declared``.
    """
    unit = "N" if datasets and datasets[0].input_name == "force_n" else "Pa"
    if given is None and declared is None:
        seen = (min(float(np.min(d.input)) for d in datasets),
                max(float(np.max(d.input)) for d in datasets))
        raise DesignError(
            f"the rig's input range is not known: give it (input_range=(low, high) in {unit}, "
            f"--input-range LO,HI in the data file's units, or \"input_range\": [low, high] "
            f"in {unit} in the data's sidecar); the data so far span "
            f"{seen[0]:.6g} to {seen[1]:.6g} {unit}, and a design never drives the rig "
            "beyond a range it was given")
    for what, r in (("input range", given), ("rig's declared input range", declared)):
        if r is not None and not (len(r) == 2 and all(math.isfinite(v) for v in r)
                                  and r[0] < r[1]):
            raise DesignError(f"the {what} {r!r} is not a range: give two finite numbers, "
                              "low < high")
    if given is None:
        return (float(declared[0]), float(declared[1]))
    if declared is not None and (given[0] < declared[0] or given[1] > declared[1]):
        raise DesignError(
            f"the input range {given[0]:.6g} to {given[1]:.6g} {unit} reaches beyond the rig's "
            f"declared {declared[0]:.6g} to {declared[1]:.6g} {unit} (its sidecar's "
            "\"input_range\"); give a range inside it")
    return (float(given[0]), float(given[1]))


def _frequency_band(duration_s: float, rate_hz: float) -> tuple[float, float]:
    """The frequencies a candidate may use: at least two periods in the record, and at
    least ten samples a period (and at most 20 Hz, beyond a muscle's response)."""
    return max(2.0 / duration_s, 0.05), min(rate_hz / 10.0, 20.0)


def candidate_experiments(rng: np.random.Generator, n: int, *, low: float, high: float,
                          duration_s: float, sample_rate_hz: float,
                          loads: Sequence[float | None] = (None,),
                          first_input: np.ndarray | None = None) -> list[Experiment]:
    """``n`` candidate experiments: the repeat of the first input and the default chirp
    first (where ``n`` allows), then random members of :data:`FAMILIES` in turn.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the families' settings.
    n : int
        How many, >= 1.
    low, high : float
        The input range, SI.
    duration_s, sample_rate_hz : float
        Each experiment's length and rate.
    loads : sequence of float or None
        Dead loads to choose from, kg (0: none; None: the first data set's); each
        candidate takes one at random, the repeat and the default chirp the first.
    first_input : numpy.ndarray, optional
        The first data set's input; its repeat is a candidate where it lies in the range.

    Returns
    -------
    list of Experiment
    """
    f_lo, f_hi = _frequency_band(duration_s, sample_rate_hz)
    span = high - low
    out: list[Experiment] = []
    load0 = loads[0]
    if first_input is not None and low <= float(np.min(first_input)) \
            and float(np.max(first_input)) <= high:
        out.append(Experiment("repeat", duration_s, sample_rate_hz,
                              {"signal": np.asarray(first_input, dtype=float)}, load0))
    out.append(Experiment("default_chirp", duration_s, sample_rate_hz,
                          {"f0_hz": max(0.1, f_lo), "f1_hz": min(3.0, f_hi),
                           "amplitude": 0.5 * span, "offset": low + 0.5 * span}, load0))
    k = 0
    while len(out) < n:
        family = FAMILIES[k % len(FAMILIES)]
        k += 1
        amplitude = span * 0.5 * rng.uniform(0.2, 1.0)
        offset = rng.uniform(low + amplitude, high - amplitude)
        f = np.sort(np.exp(rng.uniform(np.log(f_lo), np.log(f_hi), 2)))
        load = loads[int(rng.integers(len(loads)))]
        if family == "chirp":
            settings = {"f0_hz": float(f[0]), "f1_hz": float(f[1]),
                        "amplitude": float(amplitude), "offset": float(offset)}
        elif family == "sine":
            settings = {"f0_hz": float(f[0]), "amplitude": float(amplitude),
                        "offset": float(offset)}
        elif family == "noise":
            settings = {"f0_hz": float(f[0]), "f1_hz": float(f[1]),
                        "amplitude": float(amplitude), "offset": float(offset),
                        "seed": int(rng.integers(2**31))}
        else:  # steps: holds of a tenth to a fiftieth of the record
            n_levels = int(rng.integers(10, 51))
            settings = {"levels": [float(v) for v in rng.uniform(low, high, n_levels)],
                        "hold_s": duration_s / n_levels}
        out.append(Experiment(family, duration_s, sample_rate_hz, settings, load))
    return out[:n]
