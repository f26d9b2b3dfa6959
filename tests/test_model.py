"""Parameters, priors and model composition."""

import math

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.model.model import BASE_PARAMETERS, CARRIAGE_MASS_KG, PMA_MASS_KG


def test_paper_values_are_the_defaults():
    model = pb.Model()
    assert model.parameter_names == ("alpha", "beta", "gamma", "d", "K_e", "p_dz")
    for name, value in pb.PAPER_VALUES.items():
        assert model.defaults[name] == value
    assert pb.PAPER_VALUES["p_dz"] == 66922.0  # 66.922 kPa in Pa


def test_derived_area_balances_the_static_equation():
    v = pb.PAPER_VALUES
    area = pb.derive_area()
    x, p = 0.085, 0.4e6
    weight = (CARRIAGE_MASS_KG + PMA_MASS_KG) * 9.81
    x0 = -weight / v["K_e"]
    # loading branch by explicit quadrature of dz/dx = alpha - (beta + gamma) z
    xs = np.linspace(x0, x, 200001)
    z = 0.0
    h = xs[1] - xs[0]
    for _ in xs[1:]:
        k1 = v["alpha"] - (v["beta"] + v["gamma"]) * z
        k2 = v["alpha"] - (v["beta"] + v["gamma"]) * (z + h * k1)
        z += 0.5 * h * (k1 + k2)
    expected = (v["K_e"] * x + z + weight) / (p - v["p_dz"])
    assert area == pytest.approx(expected, rel=1e-6)
    assert 2.1e-4 < area < 2.2e-4
    # without gravity to lift, the same extension needs less area
    assert pb.derive_area(gravity_sign=0.0) < area


def test_composition_names_and_order():
    model = pb.Model(["regulator_lag", "coulomb_friction"])
    assert model.parameter_names[-3:] == ("tau_reg", "F_c", "v_c")
    assert model.free_names[-2:] == ("tau_reg", "F_c")  # v_c is a fixed setting
    assert model.fixed == {"v_c": 2e-3}
    freed = pb.Model(["coulomb_friction"], free=["v_c"])
    assert "v_c" in freed.free_names
    assert model.with_effects("cubic_stiffness").effect_names == (
        "regulator_lag", "coulomb_friction", "cubic_stiffness")


def test_force_rig_has_no_dead_zone_parameter():
    model = pb.Model(rig=pb.Rig.force_oscillator(2.0))
    assert "p_dz" not in model.parameter_names
    assert model.rig.input_name == "force_n"


def test_theta_from_mapping_and_array():
    model = pb.Model()
    theta = model.theta({"K_e": [600.0, 700.0]})
    assert theta.shape == (2, 6)
    assert theta[1, model.index("K_e")] == 700.0
    assert theta[0, model.index("alpha")] == pb.PAPER_VALUES["alpha"]
    assert np.array_equal(model.theta(theta), theta)


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"K": 1.0}, "'K' is not a parameter"),
        ({"d": -1.0}, "parameter d = -1.0 .* outside its bounds"),
        ({"p_dz": -1.0}, "p_dz .* outside its bounds"),
        ({"K_e": [1.0, 2.0], "d": [1.0, 2.0, 3.0]}, "different lengths"),
        (np.zeros(5), "does not match the model's 6 parameters"),
    ],
)
def test_theta_rejects_bad_parameters(params, match):
    with pytest.raises(pb.ModelError, match=match):
        pb.Model().theta(params)


def test_overrides_must_name_parameters():
    with pytest.raises(pb.ModelError, match="'tau' is not a parameter"):
        pb.Model(priors={"tau": pb.Normal(0, 1)})
    with pytest.raises(pb.ModelError, match="must be a pmabayes Prior"):
        pb.Model(priors={"d": 3.0})
    with pytest.raises(TypeError):
        pb.Model(effect=["regulator_lag"])  # misspelt keyword is rejected, not swallowed


def _posterior(model):
    """The one joint log prior lives on the posterior; a tiny data set builds one."""
    from pmabayes.inference.density import Posterior
    from pmabayes.inference.likelihood import Likelihood
    from pmabayes.inference.noise import NoiseEstimate
    from pmabayes.synthetic import Chirp, generate_chirp_dataset

    ds = generate_chirp_dataset(n_trials=2, seed=0, chirp=Chirp(duration_s=1.0, f0_hz=0.5,
                                                                 f1_hz=1.0))
    noise = NoiseEstimate(5e-5, 0.9, 5e-6, np.zeros(3), np.eye(3))
    return Posterior(Likelihood(model, ds), noise)


def test_log_prior_respects_bounds_and_overrides():
    model = pb.Model(priors={"d": pb.Uniform(100.0, 200.0)}, fixed={"beta": 1.7})
    post = _posterior(model)
    assert "beta" not in post.names  # fixed parameters have no prior
    theta = model.theta({"d": [150.0, 250.0]})[:, [model.index(n) for n in post.names]]
    lp = post.log_prior(theta)
    assert lp[1] == -np.inf  # outside the overriding prior's support
    # the sum of the free parameters' densities, the override's for d
    expected = sum(float(model.priors[n].logpdf(theta[0, j])) for j, n in enumerate(post.names))
    assert lp[0] == pytest.approx(expected, rel=1e-12)
    base = _posterior(pb.Model(fixed={"beta": 1.7})).log_prior(theta[:1])
    assert base[0] != lp[0]
    # outside a parameter's hard bounds: -inf whatever the prior
    below = theta[:1].copy()
    below[0, post.names.index("K_e")] = -1.0
    assert post.log_prior(below)[0] == -np.inf


@pytest.mark.parametrize(
    "prior",
    [pb.Uniform(-1.0, 3.0), pb.Normal(2.0, 0.5), pb.LogNormal(3.0, 0.4), pb.HalfNormal(2.0)],
)
def test_prior_density_integrates_to_one_and_matches_samples(prior):
    rng = np.random.default_rng(4)
    draws = prior.sample(rng, 200_000)
    lo, hi = np.quantile(draws, [0.0005, 0.9995])
    grid = np.linspace(lo, hi, 20001)
    mass = np.trapezoid(np.exp(prior.logpdf(grid)), grid)
    assert mass == pytest.approx(0.999, abs=3e-3)
    # the sample mean agrees with the density's mean
    mean = np.trapezoid(grid * np.exp(prior.logpdf(grid)), grid) / mass
    assert draws.mean() == pytest.approx(mean, rel=0.02, abs=0.01)
    assert np.array_equal(prior.sample(np.random.default_rng(4), 10), draws[:10])


def test_parameter_validation():
    with pytest.raises(ValueError, match="outside its bounds"):
        pb.Parameter("k", "N/m", -1.0, pb.HalfNormal(1.0), bounds=(0.0, 10.0))
    with pytest.raises(ValueError, match="identifier"):
        pb.Parameter("not ok", "N", 1.0, pb.HalfNormal(1.0))


def test_every_base_parameter_is_documented():
    for p in BASE_PARAMETERS:
        assert p.unit and p.description and p.latex
        assert p.in_bounds(p.default)
        lo, hi = p.prior.support()
        assert lo <= p.default <= hi and not math.isinf(p.prior.logpdf(p.default))


@pytest.mark.parametrize("text", ["LogNormal(median=25, sigma=1.5)", "Uniform(0, 300000)",
                                  "Normal(-1100, 500)", "HalfNormal(50)",
                                  "LogNormal(1.2345678901e-07, 0.5)"])
def test_a_prior_reads_back_from_its_printed_form(text):
    from pmabayes.model.parameters import parse_prior

    prior = parse_prior(text)
    assert parse_prior(str(prior)) == prior
    assert parse_prior(text.lower().replace(" ", "")) == prior


@pytest.mark.parametrize(("text", "pattern"), [
    ("Beta(1, 2)", r"not understood; write one of Uniform\(low, high\)"),
    ("Normal(0)", r"Normal takes \(mu, sigma\)"),
    ("Normal(0, wide)", r"'wide' is not a number"),
    ("LogNormal(-1, 1)", r"median > 0"),
])
def test_a_bad_prior_says_what_is_accepted(text, pattern):
    from pmabayes.model.parameters import parse_prior

    with pytest.raises(ValueError, match=pattern):
        parse_prior(text)


def test_the_priors_a_fit_used_come_back_with_its_model():
    import json

    from conftest import fake_fit

    from pmabayes.inference.fitfile import model_from_fit
    from pmabayes.model.parameters import LogNormal

    tree = fake_fit()
    info = json.loads(tree.attrs["pmabayes"])
    for row in info["model"]["parameters"]:
        if row["name"] == "K_e":
            row["prior"] = "LogNormal(median=50000, sigma=2)"
    tree.attrs["pmabayes"] = json.dumps(info)
    model = model_from_fit(tree)
    assert model.priors["K_e"] == LogNormal(5e4, 2.0)
    assert model.priors["alpha"] == pb.Model().priors["alpha"]


def test_the_cli_takes_priors_and_refuses_bad_ones(capsys):
    from pmabayes.cli import _parser
    from pmabayes.model.parameters import LogNormal

    args = _parser().parse_args(["fit", "d.csv", "--out", "f.nc",
                                 "--prior", "K_e=LogNormal(5e4, 2)"])
    assert dict(args.prior) == {"K_e": LogNormal(5e4, 2.0)}
    with pytest.raises(SystemExit):
        _parser().parse_args(["fit", "d.csv", "--out", "f.nc", "--prior", "K_e=Gamma(2, 1)"])
    assert "not understood" in capsys.readouterr().err
