"""``quadratic_sensor``: a position sensor that reads ``x + c_qs x^2``.

Its reading against the base model's positions, its null, its inverse (the closed
loop's computed torque unwinds the reading with it), its prior on a force rig, and that
``diagnose``'s score test and ``pmabayes design`` take it as a candidate.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.synthetic import Chirp, generate_chirp_dataset

DT = 5e-3
#: 4 s of a 0.2-2 Hz chirp over 0-500 kPa: the muscle's whole stroke (about 0.1 m)
T = np.arange(int(4.0 / DT)) * DT
U = 2.5e5 - 2.5e5 * np.cos(2 * np.pi * (0.2 * T + 0.9 * T**2 / 4.0))


def _positions(effects, values=None) -> np.ndarray:
    return pb.simulate(pb.Model(effects), values, U, dt_s=DT)[0]


def test_registered_documented_and_a_candidate():
    eff = pb.get_effect("quadratic_sensor")
    assert eff.stage == "measurement" and eff.__name__ in pb.model.effects.__all__
    assert "quadratic_sensor" in pb.model.effects.registered_effects()  # diagnose tests it
    assert len(eff.description) > 300 and "residual" in eff.description
    (p,) = eff.parameters
    assert (p.name, p.unit, p.null) == ("c_qs", "1/m", 0.0) and p.description and p.latex
    assert p.bounds[0] <= p.default <= p.bounds[1] and p.default != p.null
    p.check_prior()
    guide = (Path(__file__).parents[1] / "docs" / "guide" / "model.md").read_text()
    assert "| `quadratic_sensor` | measurement | `c_qs` [1/m] |" in guide


def test_the_reading_is_the_position_plus_its_square_and_the_motion_is_unchanged():
    x = _positions([])
    assert np.ptp(x) > 0.05  # the stroke the prior is scaled to
    for c in (-1.5, 0.7):
        y = _positions(["quadratic_sensor"], {"c_qs": c})
        np.testing.assert_allclose(y, x + c * x**2, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(_positions(["quadratic_sensor"], {"c_qs": 0.0}), x)


def test_inverse_undoes_the_reading_with_its_slope():
    eff = pb.get_effect("quadratic_sensor")
    x = np.linspace(-0.01, 0.1, 12).reshape(6, 2)
    for c in (-2.0, 0.0, 3.0):
        q = np.full((2, 1), c)
        y = x.copy()
        eff.physics(q, np.arange(6) * DT, y)
        for k in range(6):
            for i in range(2):
                back, slope = eff.inverse(q[i], k * DT, y[k, i])
                assert back == pytest.approx(x[k, i], rel=1e-12, abs=1e-15)
                assert slope == pytest.approx(1.0 / (1.0 + 2.0 * c * x[k, i]), rel=1e-9)
    # beyond the map's fold no position gives the reading: the fold, and no slope
    back, slope = eff.inverse(np.array([-2.0]), 0.0, 0.2)
    assert (back, slope) == (0.25, 0.0)


def test_force_rig_prior_follows_the_amplitude():
    prior = pb.get_effect("quadratic_sensor").force_rig_priors(1e4, 0.002, 2.0)["c_qs"]
    assert prior.quantile(0.5) == pytest.approx(0.0, abs=1e-12)
    assert prior.quantile(0.8413) == pytest.approx(0.2 / 0.002, rel=1e-3)


def test_the_score_test_flags_a_hidden_quadratic_sensor():
    from pmabayes.criticism.scores import rank_effects
    from pmabayes.inference.density import Posterior
    from pmabayes.inference.likelihood import Likelihood
    from pmabayes.inference.noise import estimate_noise
    from pmabayes.inference.search import find_map

    chirp = Chirp(duration_s=5.0, f0_hz=0.3, f1_hz=3.0)
    ds = generate_chirp_dataset(n_trials=6, seed=3, chirp=chirp,
                                effects={"quadratic_sensor": -1.0})
    lik = Likelihood(pb.Model(), ds)
    noise = estimate_noise(lik)
    values = find_map(Posterior(lik, noise), rng=np.random.default_rng(0)).values
    ranked = rank_effects(lik, noise, values,
                          candidates=("quadratic_sensor", "regulator_lag", "coulomb_friction"))
    top = ranked[0]
    assert (top.effect, top.significant) == ("quadratic_sensor", True), ranked
    assert top.estimate["c_qs"] < 0


def test_the_design_takes_it_as_a_candidate():
    from pmabayes.design.fits import does_not_act

    chirp = Chirp(f0_hz=0.1, f1_hz=0.5, duration_s=6.0, p_min_pa=1.0e5, p_max_pa=1.6e5,
                  sample_rate_hz=200.0)
    ds = generate_chirp_dataset(n_trials=2, seed=3, chirp=chirp)
    assert does_not_act([ds], [], "quadratic_sensor") is None
