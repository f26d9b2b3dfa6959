"""The model linearised along a trajectory (pmabayes.model.linearise): every built-in force
effect, whatever its signature, through one interface, and the discrepancy step's linear
response built on it."""

import ast
from pathlib import Path

import numpy as np
import pytest

import pmabayes as pb
from pmabayes.model.effects import Effect, get_effect
from pmabayes.model.linearise import effect_forces, linearise
from pmabayes.synthetic import Chirp, generate_chirp_dataset

ROOT = Path(__file__).resolve().parents[1]
FORCE_EFFECTS = sorted(n for n in pb.registered_effects() if get_effect(n).stage == "force")
CHIRP = Chirp(duration_s=5.0, f0_hz=0.3, f1_hz=3.0)


def effect_calls(paths, root: Path = ROOT) -> list[str]:
    """Places in ``paths`` that reach an effect's ``physics`` or ``advance``: any
    ``.physics``, an ``.advance`` taken as a value or called with an effect's arguments
    (``q, state, x0, x1, h``: two or more; a progress bar's ``advance(n)`` takes one),
    and ``getattr`` of either name."""
    found = []
    for path in paths:
        tree = ast.parse(path.read_text())
        called = {id(n.func): len(n.args) + len(n.keywords) for n in ast.walk(tree)
                  if isinstance(n, ast.Call)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == "physics":
                hit = True
            elif isinstance(node, ast.Attribute) and node.attr == "advance":
                hit = called.get(id(node), 2) >= 2
            elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "getattr":
                hit = any(isinstance(a, ast.Constant) and a.value in ("physics", "advance")
                          for a in node.args[1:2])
            else:
                hit = False
            if hit:
                found.append(f"{path.relative_to(root)}:{node.lineno}")
    return found


def test_nothing_outside_the_model_layer_calls_an_effects_physics_or_advance():
    """Effects have several signatures (plain, reading z, with a state): only the model
    layer (code generation, linearisation, ``Effect.force_n``) knows them, so no other
    source reaches ``physics`` or ``advance``."""
    model = ROOT / "pmabayes" / "model"
    paths = [path for folder in ("pmabayes", "analyses") for path in (ROOT / folder).rglob("*.py")
             if model not in path.parents]
    found = effect_calls(paths)
    assert not found, ("ask the model layer (pmabayes.model.linearise, Effect.force_n) "
                       f"instead: {found}")


def test_the_effect_call_check_can_fail(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("f = eff.physics\n"
                   "r = eff.advance(q, s, x0, x1, h)\n"
                   "bar.advance()\n"
                   "bar.advance(3)\n"
                   "g = eff.advance\n"
                   "h = getattr(eff, 'physics')\n")
    found = effect_calls([bad], root=tmp_path)
    assert sorted(found, key=lambda s: int(s.split(":")[1])) == [
        "bad.py:1", "bad.py:2", "bad.py:5", "bad.py:6"]


def trajectory(n=60, dt=1e-3):
    """A small smooth trajectory with reversals, and its pressure and hysteretic force."""
    t = np.arange(n) * dt
    w = 2 * np.pi * 20.0
    x = 0.02 + 0.006 * np.sin(w * t)
    v = 0.006 * w * np.cos(w * t)
    p = 3e5 + 1e5 * np.sin(0.5 * w * t)
    z = 8.0 * np.cos(w * t + 0.4)
    return x, v, p, z, dt


def theta_of(model):
    """The defaults, with every effect's parameters that sit at their null moved off it
    (so that each effect acts)."""
    values = dict(model.defaults)
    for eff in model.effects:
        for par in eff.parameters:
            if par.null is not None and values[par.name] == par.null:
                values[par.name] = par.null + 0.3
    return model.theta(values)[0]


@pytest.mark.parametrize("name", FORCE_EFFECTS)
def test_every_force_effect_and_its_derivatives_along_a_trajectory(name):
    """The force and its x, v, z derivatives against central differences of the force
    (the states re-advanced along the shifted trajectory, their share added)."""
    model = pb.Model([name])
    th = theta_of(model)
    x, v, p, z, dt = trajectory()
    ef = effect_forces(model, th, x, v, p, z, dt)
    assert np.all(np.isfinite(ef.force_n)) and np.any(ef.force_n != 0.0)
    eff = get_effect(name)
    assert ef.state_names == ((eff.state,) if eff.state else ())

    def moved(**kw):
        args = dict(x_m=x, v_m_s=v, p_pa=p, z_n=z) | kw
        return effect_forces(model, th, args["x_m"], args["v_m_s"], args["p_pa"],
                             args["z_n"], dt)

    for key, arr, deriv, h in (("x_m", x, "dforce_dx", 1e-7), ("v_m_s", v, "dforce_dv", 1e-6),
                               ("z_n", z, "dforce_dz", 1e-5)):
        up, down = moved(**{key: arr + h}), moved(**{key: arr - h})
        total = (up.force_n - down.force_n) / (2 * h)
        through_states = np.sum(ef.dforce_dstate * (up.states - down.states) / (2 * h), axis=0)
        expected = getattr(ef, deriv) + through_states
        # the differences' own rounding: a few ulps of the force over 2 h
        tol = 1e-5 * np.max(np.abs(total)) + 1e-14 * np.max(np.abs(ef.force_n) + 1.0) / h
        assert np.max(np.abs(expected - total)) <= tol, (name, key)
    for j in range(len(ef.state_names)):  # the force's derivative in its state
        h = 1e-6 * (np.max(np.abs(ef.states[j])) + 1e-6)
        if eff.extended():
            f = [eff.physics(np.ascontiguousarray(th[sl]), x[5], v[5], p[5], z[5],
                             ef.states[j, 5] + d)[0]
                 for e, sl in model.effect_slices() if e is eff for d in (h, -h)]
            assert ef.dforce_dstate[j, 5] == pytest.approx((f[0] - f[1]) / (2 * h), rel=1e-6)


def test_the_maxwell_creep_state_and_its_rate():
    """The creep's stretch follows u' = v - u / tau: its linearised rate is exactly that."""
    model = pb.Model(["maxwell_creep"])
    th = theta_of(model)
    tau = th[model.index("tau_m")]
    x, v, p, z, dt = trajectory(n=200)
    ef = effect_forces(model, th, x, v, p, z, dt)
    rate = ef.state_rate[0]
    assert np.allclose(rate[:, 0], -1.0 / tau, rtol=1e-6)
    assert np.allclose(rate[:, 1], 0.0, atol=1e-6 / tau)
    assert np.allclose(rate[:, 2], 1.0, rtol=1e-6)
    # the state itself: u' = v - u / tau integrated from rest agrees with the advanced one
    u = np.zeros_like(x)
    for k in range(x.size - 1):  # x is smooth: the trapezoidal rule is accurate here
        u[k + 1] = (u[k] * (1 - dt / (2 * tau)) + (x[k + 1] - x[k])) / (1 + dt / (2 * tau))
    assert np.max(np.abs(ef.states[0] - u)) < 1e-4 * np.max(np.abs(u))
    lin = linearise(model, th, x, v, p, z, dt)
    assert lin.a.shape == (x.size, 4, 4) and lin.a[0, 1, 3] < 0.0  # k_m u opposes extension


class ProbeCubic(Effect):
    """A probe force c x^3, unregistered: the extra force whose response is checked."""

    __test__ = False
    name = "probe_cubic"
    stage = "force"
    parameters = (pb.Parameter("c_probe", "N/m^3", 0.0, pb.Normal(0.0, 1.0), null=0.0),)
    description = "c x^3, for the test."

    @staticmethod
    def physics(q, x, v, p):
        return q[0] * x * x * x, 3.0 * q[0] * x * x, 0.0


@pytest.mark.parametrize("name", FORCE_EFFECTS + ["bouc_wen_exponent"])
def test_the_linear_response_to_a_force_for_every_effect(name):
    """The discrepancy step's linearised model, with each built-in force effect (and the
    hysteresis law's), answers an extra force x^3 as the simulator does."""
    from pmabayes.criticism.discrepancy.response import force_response, linearised_plant
    from pmabayes.model.simulator import simulate_dataset

    ds = generate_chirp_dataset(n_trials=1, seed=1, chirp=CHIRP)
    model = pb.Model([name])
    values = dict(zip(model.parameter_names, theta_of(model), strict=True))
    sim = simulate_dataset(model, values, ds, states=True)
    ext = model.with_effects(ProbeCubic)
    fd = (simulate_dataset(ext, {**values, "c_probe": 1.0}, ds)[0]
          - simulate_dataset(ext, {**values, "c_probe": 0.0}, ds)[0])
    plant = linearised_plant(model, values, sim, ds.dt_s)
    g = force_response(plant, sim.true_position_m[0][None] ** 3)[0]
    assert np.max(np.abs(fd)) > 1e-8
    assert np.max(np.abs(g - fd)) < 0.01 * np.max(np.abs(fd)), name


def test_the_discrepancy_step_runs_on_a_model_with_creep():
    """The user's loop: data with a lag the model lacks, diagnosed with maxwell_creep (a
    state) or pressure_hysteresis (reads z) in the model; the missing force is estimated
    through the linearised model (at the model's defaults: no fit, to stay fast)."""
    from pmabayes.criticism.discrepancy import estimate_discrepancy
    from pmabayes.criticism.observed import simulate_states
    from pmabayes.inference.likelihood import Likelihood
    from pmabayes.inference.noise import group_noise

    ds = generate_chirp_dataset(n_trials=3, seed=5,
                                chirp=Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=3.0),
                                effects={"regulator_lag": {"tau_reg": 0.05}})
    for effects in (["maxwell_creep"], ["pressure_hysteresis"]):
        model = pb.Model(effects)
        lik = Likelihood(model, ds)
        noise, _ = group_noise([lik], "auto")
        values = dict(model.defaults)
        sim, _ = simulate_states(lik, model, values, None, 1)
        found = estimate_discrepancy(lik, noise, values, sim, plugin_dir=False, verify=False)
        # a lag is a timing problem, not a force: it says so, from a finite estimate
        assert np.isfinite(found.energy_after) and found.text, effects
