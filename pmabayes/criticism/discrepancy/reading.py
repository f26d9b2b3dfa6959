"""Is the missing piece in the reading rather than a force? Errors of the position
sensor (a gain, a drift of its zero, a delay, backlash) added to the model's output
directly, against the flexible force in the states.

A force acts through the muscle's dynamics; an error of the sensor is added to the
position read. When a few such reading errors predict left-out trials as well as the
flexible force does, a force proposal would only imitate them: the verdict says the
missing piece is not a force instead.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from pmabayes.criticism.discrepancy.problem import LinearProblem
from pmabayes.criticism.discrepancy.regression import loo_scores
from pmabayes.criticism.elpd import paired_difference

__all__ = ["ReadingError", "play", "reading_error"]


#: half-widths of the play scanned for backlash of the sensor, m (0.05 to 1.6 mm by
#: factors of sqrt(2): a play off by more than that is imitated better by a force)
#:
#: :meta hide-value:
PLAY_HALF_WIDTHS_M = tuple(0.05e-3 * 2.0 ** (k / 2) for k in range(11))

#: reading errors combined at most
MAX_TERMS = 2


@dataclass(frozen=True)
class ReadingError:
    """The best few reading errors, and how they compare with the flexible force.

    Attributes
    ----------
    terms : tuple of str
        The errors in words.
    elpd_vs_force : float
        Their leave-one-out ELPD minus the flexible force's (>= about 0: as good).
    se : float
        Its standard error.
    elpd_gain : float
        Their ELPD gain over the model alone.
    """

    terms: tuple
    elpd_vs_force: float
    se: float
    elpd_gain: float

    @property
    def as_good(self) -> bool:
        """Whether the reading errors predict left-out data as well as the flexible force
        (within one standard error: a force in z two below was once called a reading
        error) and clearly better than the model alone."""
        return bool(self.elpd_vs_force > -max(self.se, 2.0)
                    and self.elpd_gain > max(2.0 * self.se, 2.0))


def play(x: np.ndarray, half_m: float) -> np.ndarray:
    """A position read through backlash: the reading stays until the position leaves a
    band of ``half_m`` either side of it (it starts where the position starts)."""
    out = np.empty_like(x)
    r = float(x[0]) if x.size else 0.0
    for k, xk in enumerate(x):
        if xk - r > half_m:
            r = xk - half_m
        elif r - xk > half_m:
            r = xk + half_m
        out[k] = r
    return out


def _columns(problem: LinearProblem) -> tuple[list, np.ndarray]:
    """The reading errors' words and their columns ``(n, k)`` (errors added to the
    position read, at unit size)."""
    sim = problem.sim
    x, v = sim.true_position_m[0], sim.velocity_m_s[0]
    t = np.arange(x.size) * problem.dataset.dt_s
    words = ["a gain error of the position sensor (an error proportional to the position)",
             "a drift of the sensor's zero in time",
             "a delay or lag of the reading (an error proportional to the velocity)"]
    cols = [x - x.mean(), t, v]
    for half in PLAY_HALF_WIDTHS_M:
        words.append(f"backlash of about {2e3 * half:.2g} mm between the muscle and its "
                     "sensor")
        cols.append(play(x, half) - x)
    return words, np.stack(cols, axis=1)


def reading_error(problem: LinearProblem, loo_full: np.ndarray, loo_none: np.ndarray
                  ) -> ReadingError | None:
    """The best combination of at most :data:`MAX_TERMS` reading errors by leave-one-out
    ELPD, with the model's parameters readjusted, against the flexible force.

    Parameters
    ----------
    problem : LinearProblem
        The diagnosed model's linear problem.
    loo_full : numpy.ndarray
        Leave-one-out scores of the flexible force.
    loo_none : numpy.ndarray
        Those of the model alone (its parameters readjusted).

    Returns
    -------
    ReadingError or None
        None when no reading error changes the output.
    """
    words, raw = _columns(problem)
    white = problem.whiten_cols(raw)
    scale = np.linalg.norm(white, axis=0)
    keep = scale > 0
    if not keep.any():
        return None
    words = [w for w, k in zip(words, keep, strict=True) if k]
    raw, white = raw[:, keep] / scale[keep], white[:, keep] / scale[keep]
    best = None
    for size in range(1, MAX_TERMS + 1):
        for support in itertools.combinations(range(len(words)), size):
            if sum("backlash" in words[j] for j in support) > 1:
                continue  # one play
            loo = loo_scores(problem, [], [], extra=(white, raw, list(support)))
            score = float(np.sum(loo))
            if best is None or score > best[0]:
                best = (score, loo, support)
    _, loo, support = best
    d, se = paired_difference(loo, loo_full)
    gain, gain_se = paired_difference(loo, loo_none)
    return ReadingError(tuple(words[j] for j in support), d, max(se, gain_se), gain)
