"""What makes the loop fast, checked for what it must keep: the noise's own search split
by noise group finds the optimum the joint search found (or a higher one), and the
candidates' simulators compiled in a background process land in the disk cache."""

import numpy as np

import pmabayes as pb
from pmabayes.inference.density import Posterior
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.noise.repeats import _minimise_noise
from pmabayes.inference.noise_start import _noise_start
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset


def _two_records():
    chirp = Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=3.0, sample_rate_hz=200.0)
    ds = [generate_chirp_dataset(n_trials=1, seed=s, chirp=chirp,
                                 noise=MeasurementNoise(30e-6, corr_s, encoder_counts_per_m=None))
          for s, corr_s in ((1, 0.002), (2, 0.05))]
    model = pb.Model()
    liks = [Likelihood(model, d) for d in ds]
    return ds, model, Posterior(liks, [None, None], names=["a", "b"])


def test_the_noise_search_by_group_reaches_the_joint_search_optimum():
    # two records without repeats: each its own noise group, sampled with the model
    _, model, post = _two_records()
    assert post.noise_columns(0) and post.noise_columns(1)
    assert post.members(0) == [0] and post.members(1) == [1]
    theta = np.array([[p.default for p in post.parameters]])
    z = post.to_unconstrained(theta)[0]
    split = _noise_start(post, z)
    # the same search over both groups at once (as before the split)
    cols = np.arange(post.n_searched, post.ndim)
    outputs = [np.atleast_2d(post.simulate(theta, e)[0]) for e in range(2)]

    def neg(u):
        zz = np.repeat(z[None], np.atleast_2d(u).shape[0], axis=0)
        zz[:, cols] = np.atleast_2d(u)
        return -post.log_prob_z(zz, outputs=outputs)

    joint = z.copy()
    # from the split's optimum moved in the noise's scales (unbounded coordinates)
    scales = [c for g in (0, 1) for c in np.array(post.noise_columns(g))[[0, 2]]]
    u0 = split.copy()
    u0[scales] += 0.5
    joint[cols] = _minimise_noise(neg, u0[cols])
    for g in (0, 1):  # kept off a bound, as the split's start is
        gc = post.noise_columns(g)
        joint[gc] = post.likelihoods[g].noise.clip_start(joint[gc], post.upper[gc])
    lp_split, lp_joint = post.log_prob_z(np.stack([split, joint]))
    assert np.array_equal(split[: post.n_searched], z[: post.n_searched])
    assert lp_split >= lp_joint - 1e-6
    # the two records' noise correlations are told apart (0.08 and 0.90 generated)
    rho = post.to_natural(split[None])[0, [post.noise_columns(g)[1] for g in (0, 1)]]
    assert rho[1] > rho[0] + 0.2


def test_the_likelihood_of_some_experiments_is_their_sum():
    _, _, post = _two_records()
    theta = np.array([[p.default for p in post.parameters]])
    outputs = [np.atleast_2d(post.simulate(theta, e)[0]) for e in range(2)]
    lp, ll, _ = post.evaluate(theta, return_x=False, outputs=outputs)
    parts = [post.evaluate(theta, return_x=False, outputs=outputs, experiments=[e])[1]
             for e in range(2)]
    assert np.allclose(ll, parts[0] + parts[1])


def test_candidate_simulators_compile_in_the_background(tmp_path, monkeypatch):
    import pmabayes.model.kernels as kernels
    from pmabayes.criticism.scores import compile_candidates

    monkeypatch.setenv("PMABAYES_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(kernels, "_KERNELS", {})  # the child compiles, not inherits
    ds, model, _ = _two_records()
    proc = compile_candidates([model], [ds[0]], 1, candidates=["regulator_lag"])
    assert proc is not None
    proc.join(timeout=300)
    assert proc.exitcode == 0
    assert list((tmp_path / "kernels").rglob("*.nbi")), "nothing in numba's disk cache"


def test_refits_in_worker_processes_give_the_numbers_of_refits_here():
    import json

    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.criticism.settings import DiagnoseSettings

    ds = generate_chirp_dataset(n_trials=4, seed=3, effects={"regulator_lag": 0.045},
                                chirp=Chirp(duration_s=4.0, f0_hz=0.3, f1_hz=3.0,
                                            sample_rate_hz=200.0))
    runs = []
    for processes in (1, 2):
        s = DiagnoseSettings(candidates=("regulator_lag", "transport_delay"), max_refits=2,
                             processes=processes, discrepancy=False)
        d = diagnose(ds, settings=s, seed=0).to_dict()
        d["settings"].pop("processes")
        runs.append(json.dumps(d, sort_keys=True, default=str))
    assert runs[0] == runs[1]
    assert json.loads(runs[0])["missing"] == "regulator_lag"


def test_the_next_candidates_are_refitted_where_none_of_the_first_is_named(monkeypatch):
    import pmabayes.criticism.refits as refits
    from pmabayes.criticism.scores import EffectEvidence
    from pmabayes.criticism.settings import DiagnoseSettings
    from pmabayes.util import Progress

    ranked = [EffectEvidence(n, 10.0, 1, 1e-6, True, {}, {}, 0.0)
              for n in ("a", "b", "c", "d", "e")] + [EffectEvidence("f", 0.1, 1, 0.9, False,
                                                                    {}, {}, 0.0)]
    seen = []
    monkeypatch.setattr(refits, "_refit", lambda base, effect, s, rng: seen.append(effect)
                        or effect)
    s = DiagnoseSettings(max_refits=2, processes=1, leave_experiments_out=False)
    rng = np.random.default_rng(0)
    # none of the first two named: the next two are refitted, and no more
    monkeypatch.setattr(refits, "missing_effect", lambda r, s: None)
    monkeypatch.setattr(refits, "partial_effect", lambda r, missing=None: None)
    assert list(refits.refit_significant(None, ranked, s, rng, Progress())) == ["a", "b", "c",
                                                                                "d"]
    # the first named: nothing more
    seen.clear()
    monkeypatch.setattr(refits, "partial_effect", lambda r, missing=None: "a")
    assert list(refits.refit_significant(None, ranked, s, rng, Progress())) == ["a", "b"]
    assert seen == ["a", "b"]


def test_a_noise_search_that_cannot_leave_its_start_is_not_run():
    # a stiffness whose exact step overflows: each record's output is NaN, so its noise
    # start is not finite and the cost inf at every noise; the second group's search
    # also meets the first group's non-finite noise among its fixed prior terms
    import warnings

    _, _, post = _two_records()
    theta = np.array([[p.default for p in post.parameters]])
    theta[0, post.names.index("K_e")] = 1e300
    z = post.to_unconstrained(theta)[0]
    calls = []
    log_prob_z = post.log_prob_z

    def counted(*args, **kwargs):
        calls.append(1)
        return log_prob_z(*args, **kwargs)

    post.log_prob_z = counted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the overflow is said once, elsewhere
        found = _noise_start(post, z)
        # what the search would have returned: its simplex never leaves the start
        lik = post.likelihoods[0]
        r = lik.y_mean - post.likelihood.split(post.output(theta))[0][0]
        u0, _ = lik.noise.start(r, lik.observed, lik)
    assert len(calls) == 0
    cols = np.asarray(post.noise_columns(0))
    assert np.array_equal(found[cols], lik.noise.clip_start(u0, post.upper[cols]), equal_nan=True)
    assert not np.all(np.isfinite(found[cols]))
    assert np.array_equal(found[: post.n_searched], z[: post.n_searched])
