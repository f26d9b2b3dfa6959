"""A refit's MAP starts from the model it nests (``DiagnoseSettings.refit_search``).

A refit holds the diagnosed model with the effect at its null, so the diagnosed model's
MAP is a point of the refit's space. ``find_map``'s ``starts`` polishes from such points
beside its global search, and keeps the highest.
"""

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.inference.density import Posterior
from pmabayes.inference.likelihood import Likelihood
from pmabayes.inference.noise import estimate_noise
from pmabayes.inference.search import find_map
from pmabayes.synthetic import Chirp, generate_chirp_dataset


def test_a_start_given_is_kept_where_the_search_falls_short(monkeypatch):
    # a search made to fail (it returns the plausible box's lower corner), on a
    # pressure-dependent stiffness: its polish ends far from the MAP; a start at the
    # truth is polished to it, and kept
    import pmabayes.inference.search as search

    ds = generate_chirp_dataset(n_trials=6, seed=3, effects={"pressure_stiffness": 3e-4},
                                chirp=Chirp(duration_s=5.0, f0_hz=0.3, f1_hz=3.0))
    model = pb.Model().with_effects("pressure_stiffness")
    lik = Likelihood(model, ds)
    posterior = Posterior(lik, estimate_noise(lik))
    truth = np.array([[model.defaults[n] for n in posterior.names]])

    def corner(posterior, box, *args):
        z = box[:, 0].copy()
        return z, float(posterior.likelihood.rms_cost(posterior.output(
            posterior.to_natural(z[None])))[0])

    monkeypatch.setattr(search, "_global_search", corner)
    monkeypatch.setattr(search, "_nested_start", lambda p, b, z, cost: (z, cost, False))
    alone = find_map(posterior, rng=np.random.default_rng(0), searches=1)
    started = find_map(posterior, rng=np.random.default_rng(0), searches=1, starts=truth)
    assert started.log_posterior > alone.log_posterior + 10.0
    assert started.values["K_p"] == pytest.approx(3e-4, rel=0.05)
    assert started.rms_cost_m < 1.2 * ds.noise_floor_m


def test_refit_search_is_checked():
    from pmabayes.criticism.settings import DiagnoseSettings

    assert DiagnoseSettings().refit_search == "nested"
    with pytest.raises(ValueError, match="refit_search must be one of nested, global"):
        DiagnoseSettings(refit_search="polish")


@pytest.mark.slow
def test_a_nested_refit_finds_an_effect_a_polish_alone_misses():
    # a pressure-dependent stiffness the base model absorbs into K_e and alpha: a
    # polish from the base MAP with K_p at its null, or at its default (the truth),
    # stops at K_p = 1.2e-5 (measured), where the refit explains 7% of the excess; the
    # global search beside it finds the truth
    from pmabayes.criticism.diagnosis import diagnose
    from pmabayes.criticism.settings import DiagnoseSettings

    ds = generate_chirp_dataset(n_trials=6, seed=3, effects={"pressure_stiffness": 3e-4},
                                chirp=Chirp(duration_s=5.0, f0_hz=0.3, f1_hz=3.0))
    candidates = ("pressure_stiffness", "cubic_stiffness")
    found = {}
    for mode in ("nested", "global"):
        d = diagnose(ds, settings=DiagnoseSettings(candidates=candidates, max_refits=2,
                                                   refit_search=mode), seed=0)
        refit = next(e.refit for e in d.ranking if e.effect == "pressure_stiffness")
        found[mode] = (d.missing, refit.values["K_p"], refit.rms_m)
    assert found["nested"][0] == found["global"][0] == "pressure_stiffness"
    assert found["nested"][1] == pytest.approx(3e-4, rel=0.05)
    assert found["nested"][2] <= 1.01 * found["global"][2]
