"""The Laplace approximation and the ELPD read from it: difference steps that are never 0
or NaN, a Hessian that is not finite or not positive definite handled with its reason,
a leave-one-out ELPD from Laplace draws that does not move with the seed of its draws
(they are weighed to the posterior), and an estimate that is not reliable naming no
effect on its own."""

from __future__ import annotations

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.special import logsumexp

from pmabayes.criticism.elpd import LaplaceLoo, laplace_loo, plugin_difference
from pmabayes.criticism.prose import elpd_short, elpd_text
from pmabayes.criticism.refits import improves, missing_effect, near_twins, partial_effect
from pmabayes.criticism.results import Refit
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.inference.laplace import (
    MAX_STEP,
    MIN_STEP,
    _fd_diagonal,
    _fd_hessian,
    _scaled_hessian,
    laplace_covariance,
    steps,
)
from pmabayes.inference.search import MapResult, _open_edges

# -- steps and the Hessian ---------------------------------------------------------------


def test_steps_are_never_zero_or_nan():
    """A curvature of inf (a probe that left the support) gave a step of 0.2/sqrt(inf) = 0,
    and the Hessian 0/0 = NaN: "invalid value encountered in scalar divide" in CI."""
    curv = np.array([4.0, 0.0, np.inf, np.nan, -4.0, 1e-300, 1e300])
    u = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e6])
    h = steps(curv, u)
    assert np.all(np.isfinite(h)) and np.all(h > 0)
    assert h[0] == pytest.approx(0.1) and h[4] == pytest.approx(0.1)  # the sign ignored
    size = np.maximum(1.0, np.abs(u))
    assert np.all(h >= MIN_STEP * size) and np.all(h <= MAX_STEP * size)
    assert h[5] == MAX_STEP and h[6] == MIN_STEP * 1e6  # scaled with |u|
    for bad in (0.0, np.nan, -1e-3):
        with pytest.raises(ValueError, match="positive and finite"):
            _fd_hessian(lambda v: np.sum(v * v, axis=1), np.zeros(2), np.array([1e-3, bad]))


def test_the_probe_diagonal_is_the_hessians_to_the_bit():
    """The probe of the curvatures evaluates the diagonal's points alone (4 n instead of
    2 n (n + 1) + 1); its numbers are those of the whole Hessian's diagonal, edges and
    all."""
    a, neg = _edge_problem()
    rng = np.random.default_rng(3)
    for u in (np.zeros(3), rng.normal(size=3) * [1.0, 1.0, 1e-7]):
        h = np.array([1e-6, 3e-4, 2e-7])
        with np.errstate(over="ignore"):
            whole = np.diag(_fd_hessian(neg, u, h))
        assert np.array_equal(_fd_diagonal(neg, u, h), whole)
    with pytest.raises(ValueError, match="positive and finite"):
        _fd_diagonal(neg, np.zeros(3), np.array([1e-3, 0.0, 1e-3]))


def _edge_problem():
    """A correlated quadratic in u0, u1 and u2, whose mode sits at the edge of the support
    in u2 (the noise correlation at its guard): a probing step of 1e-6 crosses it, where
    the log density is the 1e300 stand-in."""
    a = np.array([[2.0, 1.2, 0.3], [1.2, 1.0, 0.1], [0.3, 0.1, 5.0]])

    def neg(u):
        u = np.atleast_2d(u)
        v = 0.5 * np.einsum("bi,ij,bj->b", u, a, u)
        return np.where(u[:, 2] <= 1e-7, v, 1e300)

    return a, neg


def test_a_probe_that_leaves_the_support_gives_no_nan_and_keeps_the_other_correlations():
    a, neg = _edge_problem()
    u = np.zeros(3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no 0/0, no silent overflow
        hess = _scaled_hessian(neg, u)
    assert not np.isnan(hess).any()
    assert np.allclose(hess[:2, :2], a[:2, :2], rtol=1e-4)
    opened, edges = _open_edges(hess, neg, u)
    assert edges and np.all(np.isfinite(opened))
    # only u2 is opened: the correlation of u0 and u1 is kept (a NaN column flagged
    # every row, and the covariance lost every correlation)
    assert opened[0, 1] == pytest.approx(a[0, 1], rel=1e-4)
    assert np.all(opened[2, :2] == 0.0) and opened[2, 2] > 0


def test_a_hessian_that_is_not_finite_or_not_a_curvature_is_a_stand_in_with_its_reason():
    good = np.array([[2.0, 0.5], [0.5, 1.0]])
    cov, note = laplace_covariance(good)
    assert note is None and np.allclose(cov, np.linalg.inv(good))
    cov, note = laplace_covariance(np.array([[2.0, np.nan], [np.nan, 1.0]]))
    assert np.all(np.isfinite(cov)) and np.allclose(np.diag(cov), [0.5, 1.0])
    assert "not finite in coordinates [0, 1]" in note and "diagonal stand-in" in note
    cov, note = laplace_covariance(np.array([[1.0, 0.0], [0.0, -3.0]]))
    assert np.all(np.isfinite(cov)) and "not positive definite" in note
    assert "coordinates [1] given a variance of 1e-6" in note
    # a MAP records why its covariance is a stand-in, and keeps it through its record
    res = MapResult({}, 0.0, 0.0, {}, 0.0, np.zeros(2), cov, laplace_note=note)
    assert MapResult.from_record(res.record()).laplace_note == note
    assert res.summary()["laplace_note"] == note


# -- the ELPD from Laplace draws ---------------------------------------------------------

_N, _K = 200, 6
_RNG = np.random.default_rng(7)
_Y, _C = _RNG.normal(0.0, 0.1, _K), _RNG.normal(0.0, 0.05, _K)


class _ToyLikelihood:
    """Six units: ``a`` seen through a Gaussian, ``b`` through a quartic, flat at its
    mode and steep further out, as the dead-zone pressure traded against the hysteresis
    on the design study's chirp (the Laplace approximation there is 5x too wide)."""

    def pointwise(self, x, *noise):
        x = np.atleast_2d(x)
        return -0.5 * _N * (x[:, :1] - _Y) ** 2 - _N * (x[:, 1:2] - _C) ** 4

    def mean_log_likelihood(self, x, *noise):
        return self.pointwise(x).sum(axis=1)

    def stretch_pointwise(self, x, *args):
        return None


class _ToyPosterior:
    names, ndim = ("a", "b"), 2

    def __init__(self):
        self.likelihoods = [_ToyLikelihood()]

    def to_natural(self, z):
        return np.atleast_2d(np.asarray(z, dtype=float))

    def log_prior(self, theta):
        return np.where(np.all(np.abs(theta) < 10.0, axis=1), 0.0, -np.inf)

    def log_jacobian(self, z):
        return np.zeros(np.atleast_2d(z).shape[0])

    def simulate(self, theta, e):
        return theta

    def noise_of(self, e, theta):
        return ()


def _exact_loo() -> np.ndarray:
    """Each unit's leave-one-out predictive density by quadrature (``a`` and ``b`` are
    independent in the toy)."""
    grids = (np.linspace(-1.0, 1.0, 20001)[:, None], np.linspace(-1.5, 1.5, 20001)[:, None])
    terms = (-0.5 * _N * (grids[0] - _Y) ** 2, -_N * (grids[1] - _C) ** 4)
    out = np.zeros(_K)
    for i in range(_K):
        rest = np.arange(_K) != i
        for ll in terms:
            out[i] += logsumexp(ll[:, rest].sum(1) + ll[:, i]) - logsumexp(ll[:, rest].sum(1))
    return out


def _toy_laplace(narrow: float = 1.0) -> SimpleNamespace:
    b = np.linspace(-1.5, 1.5, 20001)
    b_hat = b[np.argmax((-_N * (b[:, None] - _C) ** 4).sum(1))]
    var_b = 1.0 / (12.0 * _N * np.sum((b_hat - _C) ** 2))  # the curvature at the mode
    return SimpleNamespace(z=np.array([_Y.mean(), b_hat]),
                           covariance_z=np.diag([1.0 / (_N * _K), var_b / narrow]))


def test_the_elpd_of_laplace_draws_does_not_move_with_their_seed():
    """Laplace draws taken as posterior draws gave -226 to -278 over five seeds where the
    leave-one-out ELPD is -2.39 (each unit's harmonic mean set by the worst draw out on
    the quartic's steep flank); weighed to the posterior, they agree with it and with
    each other within a fraction of the standard error."""
    exact = _exact_loo()
    got = [laplace_loo(_ToyPosterior(), _toy_laplace(), np.random.default_rng(seed), 400, 0.9)
           for seed in range(5)]
    elpd = np.array([g.elpd for g in got])
    se = max(math.sqrt(_K * np.var(g.elpd_i)) for g in got)
    assert np.ptp(elpd) < 0.5 * se
    assert np.all(np.abs(elpd - exact.sum()) < 0.5 * se)
    assert np.allclose(got[0].elpd_i, exact, atol=0.15)
    assert all(g.reliable and g.pareto_k <= g.good_k for g in got)
    # the MAP's in-sample log likelihood rides along, for the witness
    assert np.allclose(got[0].map_i, _ToyLikelihood().pointwise(_toy_laplace().z)[0])


def test_draws_that_do_not_cover_the_posterior_are_said_to_be_unreliable():
    """A Laplace covariance ten times too narrow in b: the importance weights are
    heavy-tailed, and the estimate says so rather than print a confident number."""
    loo = laplace_loo(_ToyPosterior(), _toy_laplace(narrow=100.0), np.random.default_rng(0),
                      400, 0.9)
    assert not loo.reliable and loo.correction_k > loo.good_k
    assert "far from the posterior (Pareto k-hat" in loo.note
    # a covariance that is a stand-in is no posterior's either
    stand_in = SimpleNamespace(**vars(_toy_laplace()), laplace_note="the Hessian ...")
    loo = laplace_loo(_ToyPosterior(), stand_in, np.random.default_rng(0), 400, 0.9)
    assert not loo.reliable and "the Laplace covariance is a stand-in" in loo.note


def test_the_elpd_of_a_real_fit_stays_within_its_error_over_seeds():
    """The design study's chirp (3 s here): two seeds of the draws moved the same fit's
    ELPD from -1625 +- 23 to -11236 +- 113."""
    from pmabayes.design import fit_candidate
    from pmabayes.synthetic import Chirp, generate_chirp_dataset

    chirp = Chirp(f0_hz=0.1, f1_hz=0.5, duration_s=3.0, p_min_pa=1.0e5, p_max_pa=1.6e5,
                  sample_rate_hz=200.0)
    ds = generate_chirp_dataset(n_trials=4, seed=100, chirp=chirp,
                                effects={"regulator_lag": 0.03})
    fit = fit_candidate([ds], ["regulator_lag"], "regulator_lag", rng=np.random.default_rng(0))
    got = [laplace_loo(fit.posterior, fit.map, np.random.default_rng(seed), 200, 0.9)
           for seed in range(4)]
    elpd = np.array([g.elpd for g in got])
    se = min(math.sqrt(g.elpd_i.size * np.var(g.elpd_i)) for g in got)
    assert np.all(np.isfinite(elpd)) and np.ptp(elpd) < se
    # never above the in-sample log likelihood at the MAP, as a held-out score cannot be
    assert np.all(elpd < got[0].map_i.sum())


# -- the rule that names an effect -------------------------------------------------------

S = DiagnoseSettings()


def _sig(rms_m: float = 1.2e-4, floor_m: float = 1e-4) -> SimpleNamespace:
    band = SimpleNamespace(rms_m=rms_m, floor_m=floor_m)
    return SimpleNamespace(bands=[band], ratio=rms_m / floor_m, energy=1.1, energy_p=0.5,
                           ljung_box_p=0.5, is_adequate=lambda *_: True)


def _refit(diff: float, se: float, *, note: str | None, plugin=(math.nan, math.nan),
           explained: float = 0.95, effect: str = "regulator_lag", **more) -> Refit:
    return Refit(effect=effect, values={}, interval={}, rms_m=1.2e-4,
                 explained=explained, elpd=1000.0 + diff, elpd_diff=diff, elpd_diff_se=se,
                 contribution_m=np.zeros(3), signatures=(_sig(),), explained_rms=explained,
                 elpd_note=note, plugin_diff=plugin[0], plugin_diff_se=plugin[1], **more)


def test_an_unreliable_elpd_names_no_effect_on_its_own():
    why = "the refit's: the Laplace draws are far from the posterior (Pareto k-hat 1.20 ...)"
    reliable = _refit(50.0, 10.0, note=None)
    assert improves(reliable) and missing_effect({"regulator_lag": reliable}, S) == "regulator_lag"
    assert elpd_short(reliable) == "+50.0 ± 10.0" and "not reliable" not in elpd_text(reliable)
    # the same numbers from an unreliable estimate, with no witness or one that disagrees
    for plugin in ((math.nan, math.nan), (3.0, 4.0), (-20.0, 5.0)):
        alone = _refit(50.0, 10.0, note=why, plugin=plugin)
        assert not improves(alone)
        assert missing_effect({"regulator_lag": alone}, S) is None
        assert partial_effect({"regulator_lag": alone}) is None
        assert elpd_short(alone) == "+50.0 ± 10.0 (not reliable)"
        text = elpd_text(alone)
        assert "not reliable: " + why in text and "names nothing" in text
    # the in-sample witness at the MAPs agrees: the effect may be named, and the words
    # say on what
    witnessed = _refit(50.0, 10.0, note=why, plugin=(48.0, 9.0))
    assert improves(witnessed)
    assert missing_effect({"regulator_lag": witnessed}, S) == "regulator_lag"
    assert "+48.0 ± 9.0, agrees" in elpd_text(witnessed)
    js = witnessed.to_dict()
    assert js["elpd_note"] == why and js["plugin_diff"] == 48.0
    assert reliable.to_dict()["elpd_note"] is None


def test_the_witness_is_the_in_sample_gain_less_the_added_parameters():
    a = LaplaceLoo(0.0, np.zeros(3), {}, map_i=np.array([-10.0, -11.0, -9.0]), n_parameters=8)
    b = LaplaceLoo(0.0, np.zeros(3), {}, map_i=np.array([-12.0, -12.0, -12.0]), n_parameters=7)
    diff, se = plugin_difference(a, b)
    assert diff == pytest.approx(6.0 - 1.0)
    assert se == pytest.approx(math.sqrt(3 * np.var([2.0, 1.0, 3.0])))
    assert math.isnan(plugin_difference(a, LaplaceLoo(0.0, np.zeros(3), {}))[0])


def test_near_twins_told_apart_by_an_unreliable_elpd_alone_stay_twins():
    """The lag beats the delay by 40 ± 5 in ELPD, but from draws that do not cover the
    posterior; at the two MAPs they fit alike: the verdict must not call them told apart."""
    def pair(note_lag, map_lag):
        lag_loo = LaplaceLoo(10.0, np.array([5.0, 5.0, 5.0, 5.0]) + 10.0, {}, note=note_lag,
                             map_i=np.asarray(map_lag, dtype=float), n_parameters=8)
        delay_loo = LaplaceLoo(0.0, np.array([0.0, 1.0, -1.0, 0.0]), {},
                               map_i=np.array([0.0, 1.0, -1.0, 0.5]), n_parameters=8)
        return {"regulator_lag": _refit(60.0, 10.0, note=note_lag, plugin=(60.0, 10.0),
                                        elpd_i=lag_loo.elpd_i, loo=lag_loo),
                "transport_delay": _refit(30.0, 10.0, note=None, effect="transport_delay",
                                          elpd_i=delay_loo.elpd_i, loo=delay_loo)}

    apart = pair(None, [0.0, 1.0, -1.0, 0.5])
    assert missing_effect(apart, S) == "regulator_lag"
    assert near_twins(apart, "regulator_lag", S) == []  # reliable: 60 ± 1.4 apart
    alike = pair("the refit's: ... (Pareto k-hat 1.10 ...)", [0.1, 1.0, -1.0, 0.6])
    assert [t[0] for t in near_twins(alike, "regulator_lag", S)] == ["transport_delay"]
    told = pair("the refit's: ... (Pareto k-hat 1.10 ...)", [30.0, 31.0, 29.0, 30.5])
    assert near_twins(told, "regulator_lag", S) == []  # the MAPs tell them apart too
