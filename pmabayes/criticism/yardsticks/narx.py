"""The polynomial NARX yardstick: ``y(k) = F[y(k-1..n), u(k-1..n)]``, ``F`` a polynomial
of degree :data:`NARX_DEGREE`, its terms chosen by forward regression with orthogonal
least squares (FROLS: the error reduction ratio of Chen, Billings & Luo 1989; Billings
2013, ch. 3), built in (module ``_frols`` beside this one).

``n`` (the output and input lags, one number for both) is one of :data:`NARX_LAGS` and the
number of terms at most :data:`MAX_TERMS`; both are chosen on the training data alone,
as the other yardsticks choose their order: the terms are ranked and fitted on the first
:data:`~pmabayes.criticism.yardsticks.base.TRAIN_SHARE` of every training record, each
candidate is simulated free-run through the whole record and scored on the rest, and the
one with the fewest terms (then the shortest lags) whose error there is within
:data:`PARSIMONY` of the smallest has its coefficients refitted on the whole records (its
terms kept).

Internal sample interval. A NARX with lags of a few samples at 1 kHz sees slow dynamics
(time constants of 0.1-1 s) as ``y(k) ~ y(k-1)``: its regression is ill-conditioned and
its free run drifts. The yardstick therefore works on a coarser grid: the training
records' finest interval times the smallest integer that leaves the longest record at
most :data:`NARX_SAMPLES` samples (a 14 s record at 1 kHz: 15 ms). Every record, training
or predicted, is brought to that grid by a centred moving average one grid interval wide
(over the observed samples only: a grid point with none within half an interval is not
observed, never filled in) and linear interpolation; the prediction is interpolated back
to the record's own times. A record at another rate is therefore predicted too.

The free run starts in steady state at the record's first input: the model is run from the
training output's mean with the first input held for as many grid samples as the longest
training record has, and the record follows. No measured output enters the prediction.
A run that leaves the training output's range by :data:`DIVERGED` ranges, or overflows,
has diverged: that candidate scores infinity, and a prediction that diverges is reported
as such (:class:`~pmabayes.criticism.yardsticks.base.PredictionFailed`).

Where the training experiments' rigs declare different loads (``rig.moving_mass_kg`` in
their sidecars: the dead weight of a hanging muscle), the load is a second input, held
constant through each record; a predicted record must then declare its load too.

Input, output and load are scaled to zero mean and unit spread on the training data
before the regression (a pressure in Pa squared beside a position in m would leave the
least squares without digits); the coefficients in the JSON are those of the scaled
variables.

References
----------
S. Chen, S. A. Billings and W. Luo (1989), "Orthogonal least squares methods and their
application to non-linear system identification", *Int. J. Control* 50(5), 1873-1896.
S. A. Billings (2013), *Nonlinear System Identification: NARMAX Methods in the Time,
Frequency, and Spatio-Temporal Domains*, Wiley.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pmabayes.criticism.yardsticks._frols import free_run, frols, regressor_codes, regressors
from pmabayes.criticism.yardsticks.base import (
    TRAIN_SHARE,
    Fitted,
    LeftOut,
    PredictionFailed,
    Record,
    Yardstick,
    declared_load_kg,
)
from pmabayes.data import Dataset

__all__ = ["NARX_LAGS", "NARX_DEGREE", "MAX_TERMS", "NARX_SAMPLES", "DIVERGED", "PARSIMONY",
           "MIN_ROWS_PER_REGRESSOR", "NarxBaseline", "NarxYardstick", "fit_narx"]

#: Output and input lags tried (the same number for both).
NARX_LAGS = (1, 2, 3, 4)
#: Degree of the polynomial.
NARX_DEGREE = 2
#: Most terms a model may keep (in the order FROLS ranks them).
MAX_TERMS = 10
#: Most samples of the longest training record on the internal grid.
NARX_SAMPLES = 1000
#: Regression rows (observed grid samples of the fitting parts) needed per candidate
#: regressor of a lag; fewer and that lag is not tried.
MIN_ROWS_PER_REGRESSOR = 10
#: Share by which a candidate with more terms must beat a smaller one on the held-back
#: parts to be chosen.
PARSIMONY = 0.05
#: A free run farther than this many training output ranges from the training output's
#: mean has diverged.
DIVERGED = 100.0


# ----------------------------------------------------------------------------- the grid


def _to_grid(values: np.ndarray, dt_s: float, grid_dt_s: float) -> np.ndarray:
    """A record on the internal grid: a centred moving average one grid interval wide
    over the finite samples, then linear interpolation at the grid's times (NaN where
    no finite sample is within reach)."""
    v = np.asarray(values, dtype=float)
    width = max(1, int(round(grid_dt_s / dt_s)))
    if width > 1:
        seen = np.isfinite(v)
        kernel = np.ones(width)
        total = np.convolve(np.where(seen, v, 0.0), kernel, mode="same")
        count = np.convolve(seen.astype(float), kernel, mode="same")
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.where(count > 0, total / count, np.nan)
    at = np.arange(0.0, (v.size - 1) * dt_s * (1 + 1e-9), grid_dt_s) / dt_s
    i0 = np.minimum(np.floor(at).astype(int), v.size - 1)
    i1 = np.minimum(i0 + 1, v.size - 1)
    frac = at - i0
    with np.errstate(invalid="ignore"):
        return np.where(frac < 1e-9, v[i0], v[i0] * (1.0 - frac) + v[i1] * frac)


def _from_grid(values: np.ndarray, grid_dt_s: float, n: int, dt_s: float) -> np.ndarray:
    """A grid series back at a record's ``n`` samples of interval ``dt_s``."""
    return np.interp(np.arange(n) * dt_s, np.arange(values.size) * grid_dt_s, values)


@dataclass(frozen=True)
class _Scale:
    """Zero mean and unit spread of the training output, input and load."""

    y: tuple[float, float]
    u: tuple[float, float]
    load: tuple[float, float] | None
    #: Beyond this distance from the training output's mean (scaled) a run has
    #: diverged: DIVERGED times the training output's range.
    limit: float = math.inf

    def inputs(self, u: np.ndarray, load_kg: float | None) -> np.ndarray:
        """``(n, 1)`` scaled input, or ``(n, 2)`` with the load held constant."""
        cols = [(u - self.u[0]) / self.u[1]]
        if self.load is not None:
            cols.append(np.full(u.size, (load_kg - self.load[0]) / self.load[1]))
        return np.stack(cols, axis=1)


def _spread(values: np.ndarray) -> tuple[float, float]:
    v = values[np.isfinite(values)]
    sd = float(np.std(v))
    return float(np.mean(v)), (sd if sd > 0 else 1.0)


# ----------------------------------------------------------------------------- the model


def _term_name(code: Sequence[int], n_inputs: int) -> str:
    """``y(k-1)*u(k-2)`` of a regressor code (1001: y(k-1), 2001: first input(k-1), 3001:
    the load; SysIdentPy's coding)."""
    names = ["y", "u", "load"][: n_inputs + 1]
    parts = [f"{names[c // 1000 - 1]}(k-{c % 1000})" for c in code if c]
    return "*".join(parts) or "1"


@dataclass(frozen=True, eq=False)
class NarxBaseline(Fitted):
    """A fitted polynomial NARX model (see the module's docstring).

    Parameters
    ----------
    lag : int
        Output and input lags, in grid samples.
    grid_dt_s : float
        The internal sample interval.
    terms : numpy.ndarray
        Regressor codes of the kept terms, ``(n_terms, degree)`` (see
        ``pmabayes.criticism.yardsticks._frols``).
    coefficients : numpy.ndarray
        Their coefficients, for the scaled variables.
    scale : _Scale
        The training data's means and spreads.
    burn_in : int
        Grid samples of the first input held before a record (the steady start).
    rmse_m : float
        RMS error of the free run on the training records (original samples).
    scores : dict
        ``"lag n, k terms"`` to the RMS error on the held-back parts (inf: diverged).
    n_candidates : int
        Candidate regressors of the chosen lag (before FROLS kept ``n_terms``).
    coefficients_from : str
        ``"all"`` (refitted on the whole records) or ``"head"`` (the refit's free run
        diverged, so the fitting parts' coefficients were kept).
    """

    name = "narx"

    lag: int
    grid_dt_s: float
    terms: np.ndarray
    coefficients: np.ndarray
    scale: _Scale
    burn_in: int
    rmse_m: float
    scores: dict = field(default_factory=dict)
    n_candidates: int = 0
    coefficients_from: str = "all"

    @property
    def n_terms(self) -> int:
        """Number of polynomial terms kept."""
        return int(self.terms.shape[0])

    @property
    def n_parameters(self) -> int:
        """One coefficient per term."""
        return self.n_terms

    @property
    def n_inputs(self) -> int:
        """1, or 2 with the load."""
        return 1 if self.scale.load is None else 2

    def simulate(self, u: np.ndarray, dt_s: float, load_kg: float | None = None,
                 where: str = "the record") -> np.ndarray:
        """The free run of an input sampled every ``dt_s`` seconds, in m.

        Parameters
        ----------
        u : numpy.ndarray
            ``(n,)`` input.
        dt_s : float
            The input's sample interval, in s.
        load_kg : float, optional
            Its declared load (needed when the model has the load as an input).
        where : str
            The record's name for messages.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` position.

        Raises
        ------
        PredictionFailed
            When the run diverges or a load is needed and not given.
        """
        if self.scale.load is not None and load_kg is None:
            raise PredictionFailed(
                f"{where} declares no load (rig.moving_mass_kg in its sidecar) and the NARX "
                "yardstick was fitted with the load as an input: declare it")
        x = self.scale.inputs(_to_grid(np.asarray(u, float), dt_s, self.grid_dt_s), load_kg)
        y = _free_run(self, x)
        if y is None:
            raise PredictionFailed(
                f"the NARX yardstick's free-run simulation of {where} diverges (leaves "
                f"{DIVERGED:g} training ranges): its error there is infinite")
        return _from_grid(self.scale.y[0] + self.scale.y[1] * y, self.grid_dt_s,
                          np.asarray(u).size, dt_s)

    def predict_dataset(self, dataset: Dataset) -> np.ndarray:
        """The predicted trial mean of a data set (:meth:`simulate` of its input)."""
        rec = Record.of(dataset)
        return self.simulate(rec.u, rec.dt_s, declared_load_kg(dataset), rec.source)

    def to_dict(self) -> dict:
        """``lag_y``, ``lag_u``, ``degree``, ``n_terms``, ``n_parameters``, ``terms``
        (with their coefficients, scaled variables), ``grid_dt_s``, ``load_input``,
        ``coefficients_from``, ``train_rmse_m`` and ``split_rmse_m`` (candidate to
        held-back error; None where its free run diverged)."""
        return {"lag_y": self.lag, "lag_u": self.lag, "degree": NARX_DEGREE,
                "n_terms": self.n_terms, "n_parameters": self.n_parameters,
                "n_candidate_terms": self.n_candidates,
                "terms": {_term_name(c, self.n_inputs): float(v)
                          for c, v in zip(self.terms, self.coefficients, strict=True)},
                "grid_dt_s": self.grid_dt_s, "load_input": self.scale.load is not None,
                "coefficients_from": self.coefficients_from,
                "train_rmse_m": self.rmse_m,
                # JSON has no inf: a candidate whose free run diverged is null
                "split_rmse_m": {str(k): v if math.isfinite(v) else None
                                 for k, v in self.scores.items()}}


def _free_run(fitted: NarxBaseline, x: np.ndarray) -> np.ndarray | None:
    """The scaled free run of scaled grid inputs ``x`` from the steady state at their first
    row (``burn_in`` rows of it first, from the training mean); None when it diverges."""
    return _simulate(fitted.lag, fitted.terms, fitted.coefficients, x, fitted.burn_in,
                     fitted.scale.limit)


def _simulate(lag: int, terms: np.ndarray, coefficients: np.ndarray, x: np.ndarray,
              burn_in: int, limit: float) -> np.ndarray | None:
    """:func:`_free_run` of given terms and coefficients: None when the run overflows or
    leaves ``limit`` (scaled)."""
    y = free_run(terms, coefficients, np.concatenate([np.repeat(x[:1], burn_in, axis=0), x]),
                 lag, limit)
    return None if y is None else y[burn_in:]


# ----------------------------------------------------------------------------- the fit


@dataclass(frozen=True)
class _Grid:
    """One training record on the internal grid, scaled: inputs, output, the fitting
    part's length and the original record."""

    x: np.ndarray
    y: np.ndarray
    cut: int
    record: Record


def _grids(records: Sequence[Record]) -> tuple[list[_Grid], _Scale, float, int]:
    """The training records on the grid, the scale, the grid interval and the burn-in."""
    dt = min(r.dt_s for r in records)
    longest = max(r.dt_s * (r.y.size - 1) for r in records)
    grid_dt = dt * max(1, math.ceil(longest / dt / NARX_SAMPLES))
    loads = [r.load_kg for r in records]
    use_load = all(v is not None for v in loads) and len(set(loads)) > 1
    ug = [_to_grid(r.u, r.dt_s, grid_dt) for r in records]
    yg = [_to_grid(np.where(r.mask("all"), r.y, np.nan), r.dt_s, grid_dt) for r in records]
    y_all = np.concatenate(yg)
    y_spread = _spread(y_all)
    span = float(np.nanmax(y_all) - np.nanmin(y_all)) / y_spread[1]
    scale = _Scale(y_spread, _spread(np.concatenate(ug)),
                   _spread(np.asarray(loads, float)) if use_load else None,
                   DIVERGED * (span if span > 0 else 1.0))
    grids = [_Grid(scale.inputs(u, r.load_kg), (y - scale.y[0]) / scale.y[1],
                   int(round(TRAIN_SHARE * y.size)), r)
             for u, y, r in zip(ug, yg, records, strict=True)]
    return grids, scale, grid_dt, max(g.y.size for g in grids)


def _rows(grids: list[_Grid], lag: int, part: str) -> tuple[np.ndarray, np.ndarray]:
    """The candidate regressors and the target of every observed row (all lags and the
    target finite) of the fitting parts (``"head"``) or of the whole records."""
    codes = regressor_codes(lag, grids[0].x.shape[1], NARX_DEGREE)
    psi, target = [], []
    with np.errstate(invalid="ignore"):
        for g in grids:
            if g.y.size <= lag + 1:
                continue
            p = regressors(g.x, g.y, codes, lag)
            t = g.y[lag:]
            keep = np.all(np.isfinite(p), axis=1) & np.isfinite(t)
            if part == "head":
                keep &= np.arange(lag, g.y.size) < g.cut
            psi.append(p[keep])
            target.append(t[keep])
    if not psi:
        return np.empty((0, 0)), np.empty(0)
    return np.concatenate(psi), np.concatenate(target)


def _n_regressors(lag: int, n_inputs: int) -> int:
    """Candidate terms of degree at most 2 in ``lag`` outputs and ``lag`` inputs (one
    load lag)."""
    return regressor_codes(lag, n_inputs, NARX_DEGREE).shape[0]


def _lstsq(psi: np.ndarray, target: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(psi, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    return np.linalg.lstsq(psi / norms, target, rcond=None)[0] / norms


def _tail_rmse(lag: int, terms: np.ndarray, coefficients: np.ndarray, grids: list[_Grid],
               burn_in: int, scale: _Scale) -> float:
    """RMS error (m) of the free run on the held-back parts of the grid records; inf
    when a run diverges."""
    errs = []
    for g in grids:
        y = _simulate(lag, terms, coefficients, g.x, burn_in, scale.limit)
        if y is None:
            return math.inf
        tail = np.arange(g.y.size) >= g.cut
        e = (g.y - y)[tail]
        errs.append(e[np.isfinite(e)])
    e = np.concatenate(errs) * scale.y[1]
    return float(np.sqrt(np.mean(e**2))) if e.size else math.inf


def _too_short(grids: list[_Grid], grid_dt: float, n_inputs: int) -> str:
    need = MIN_ROWS_PER_REGRESSOR * _n_regressors(min(NARX_LAGS), n_inputs)
    files = ", ".join(f"{g.record.source} ({g.y.size} samples)" for g in grids)
    return (f"narx yardstick left out: {files} at its internal interval of "
            f"{grid_dt * 1e3:.3g} ms hold(s) fewer than the {need} observed samples in the "
            f"first {100 * TRAIN_SHARE:.0f}% that its smallest lag ({min(NARX_LAGS)}) needs; "
            f"fit on longer records (at least {math.ceil(need / TRAIN_SHARE) + 2} samples "
            "together) to have it")


def fit_narx(records: Sequence[Record]) -> NarxBaseline:
    """The polynomial NARX yardstick, its lags and number of terms chosen on held-back
    data (see the module's docstring).

    Parameters
    ----------
    records : sequence of Record

    Returns
    -------
    NarxBaseline

    Raises
    ------
    LeftOut
        When the records are too short for its smallest lag, or when every candidate's
        free run diverges.
    """
    grids, scale, grid_dt, burn_in = _grids(records)
    n_inputs = 1 if scale.load is None else 2
    scores: dict[str, float] = {}
    tried = {}  # (n_terms, lag) to (score, terms, their indices, head coefficients)
    for lag in NARX_LAGS:
        psi, target = _rows(grids, lag, "head")
        if target.size < MIN_ROWS_PER_REGRESSOR * _n_regressors(lag, n_inputs):
            continue
        order = frols(psi, target, MAX_TERMS)[0]
        codes = regressor_codes(lag, n_inputs, NARX_DEGREE)
        for n in range(1, order.size + 1):
            coef = _lstsq(psi[:, order[:n]], target)
            score = _tail_rmse(lag, codes[order[:n]], coef, grids, burn_in, scale)
            scores[f"lag {lag}, {n} terms"] = score
            if math.isfinite(score):
                tried[n, lag] = (score, codes[order[:n]], order[:n], coef)
    if not scores:
        raise LeftOut(_too_short(grids, grid_dt, n_inputs))
    if not tried:
        raise LeftOut("narx yardstick left out: the free run of every candidate (lags "
                      f"{', '.join(map(str, NARX_LAGS))}, up to {MAX_TERMS} terms) diverges "
                      "on the training records' held-back parts")
    # the fewest terms (then the shortest lags) within PARSIMONY of the best: more terms
    # that win by the noise's share are not more model
    least = min(v[0] for v in tried.values())
    n, lag = min(k for k, v in tried.items() if v[0] <= (1.0 + PARSIMONY) * least)
    _, terms, idx, head_coef = tried[n, lag]
    psi, target = _rows(grids, lag, "all")
    fitted = dict(lag=lag, grid_dt_s=grid_dt, terms=terms, scale=scale, burn_in=burn_in,
                  scores=scores, n_candidates=_n_regressors(lag, n_inputs))
    for coef, origin in ((_lstsq(psi[:, idx], target), "all"), (head_coef, "head")):
        candidate = NarxBaseline(coefficients=coef, rmse_m=math.inf, coefficients_from=origin,
                                 **fitted)
        try:
            errs = np.concatenate([
                (r.y - candidate.simulate(r.u, r.dt_s, r.load_kg, r.source))[r.mask("all")]
                for r in records])
        except PredictionFailed:
            continue
        return NarxBaseline(coefficients=coef, rmse_m=float(np.sqrt(np.mean(errs**2))),
                            coefficients_from=origin, **fitted)
    raise LeftOut("narx yardstick left out: its chosen model's free run diverges on the "
                  "whole training records")


class NarxYardstick(Yardstick):
    """The polynomial NARX yardstick (see the module's docstring)."""

    name = "narx"
    colour = "tab:orange"
    kind = "a polynomial NARX model"
    order_words = "lags {lag_y}/{lag_u}, degree {degree}"
    size_words = "{n_terms} terms"

    def fit(self, records: Sequence[Record]) -> NarxBaseline:
        """:func:`fit_narx`."""
        return fit_narx(records)

