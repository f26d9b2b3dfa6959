"""What the input does between samples: held (a DAQ's command) or linear (samples of a
continuous signal), each within the simulator's 1e-5 m of a converged reference."""

from __future__ import annotations

import numpy as np
import pytest
from reference_solver import paper_chirp, reference_simulate
from test_simulator import (
    BENCH,
    BENCH_FS,
    BENCH_MASS,
    CHIRP,
    DT,
    LAB_EFFECTS,
    RIG_KW,
    P,
    max_err,
    multisine,
)

import pmabayes as pb
from pmabayes.simulator import BETWEEN_SAMPLES, SimulationError

#: effects whose reference admits a linear input (the reference's delay needs a hold)
LINEAR_EFFECTS = ["regulator_lag", "coulomb_friction", "cubic_stiffness",
                  "pressure_stiffness", "position_offset"]


def test_the_conventions_on_offer():
    assert BETWEEN_SAMPLES == ("hold", "linear")


def test_the_reference_converges_for_a_linear_input():
    a = reference_simulate(CHIRP, DT, **RIG_KW, **P, substeps=64, linear=True).position_m
    b = reference_simulate(CHIRP, DT, **RIG_KW, **P, substeps=128, linear=True).position_m
    assert max_err(a, b) < 1e-8


@pytest.mark.parametrize("effect", [None, *LINEAR_EFFECTS])
def test_linear_input_on_the_paper_chirp_is_within_1e5_m_of_the_reference(effect,
                                                                         record_property):
    names = [effect] if effect else []
    values = LAB_EFFECTS[effect] if effect else {}
    x = pb.simulate(pb.Model(names), values, CHIRP, dt_s=DT, between_samples="linear")[0]
    ref = reference_simulate(CHIRP, DT, **RIG_KW, **P, **values, linear=True)
    err = max_err(x, ref.position_m)
    record_property("max_abs_error_m", err)
    assert err <= 1e-5
    # the hold's half-sample delay is far larger: the convention matters
    held = reference_simulate(CHIRP, DT, **RIG_KW, **P, **values).position_m
    assert max_err(held, ref.position_m) > 10 * max(err, 1e-6)


def test_linear_input_on_the_force_oscillator_converges_with_substeps():
    """The benchmark oscillator with a linearly interpolated force: 8 substeps reach
    the accuracy requirement, and the error falls with more."""
    u = multisine()
    model = pb.Model(rig=pb.Rig.force_oscillator(BENCH_MASS))
    ref = reference_simulate(u, 1 / BENCH_FS, mass=BENCH_MASS, area=1.0, gravity_force=0.0,
                             dead_zone=False, **BENCH, linear=True).position_m
    errs = [max_err(pb.simulate(model, BENCH, u, dt_s=1 / BENCH_FS, substeps=s,
                                between_samples="linear")[0], ref) for s in (2, 8)]
    assert errs[1] <= 1e-5 and errs[1] < errs[0] / 4


def test_linear_input_batches_like_one_by_one():
    model = pb.Model(["regulator_lag"])
    _, p = paper_chirp(n=2000)
    theta = np.array([[*model.theta({})[0][:-1], tau] for tau in (0.01, 0.05)])
    both = pb.simulate(model, theta, np.stack([p, 0.8 * p]), dt_s=DT, between_samples="linear")
    for i, scale in enumerate((1.0, 0.8)):
        one = pb.simulate(model, theta[i:i + 1], scale * p, dt_s=DT, between_samples="linear")
        assert np.array_equal(both[i], one[0])


def test_hold_is_the_default_and_unchanged():
    held = pb.simulate(pb.Model(), {}, CHIRP, dt_s=DT)
    assert np.array_equal(held, pb.simulate(pb.Model(), {}, CHIRP, dt_s=DT,
                                            between_samples="hold"))


def test_an_unknown_convention_names_the_choices():
    with pytest.raises(SimulationError, match=r"'hold', 'linear'.*'bandlimited'"):
        pb.simulate(pb.Model(), {}, CHIRP, dt_s=DT, between_samples="bandlimited")


# ----------------------------------------------------------------------------- data


def _chirp_dataset(metadata: dict | None = None, between: str = "hold") -> pb.data.Dataset:
    from pmabayes.data import Dataset

    t, p = paper_chirp(n=3000)
    x = pb.simulate(pb.Model(), {}, p, time_s=t, between_samples=between)[0]
    rng = np.random.default_rng(0)
    pos = x + 2e-5 * rng.standard_normal((3, t.size))
    return Dataset(time_s=t, input=np.tile(p, (3, 1)), position_m=pos,
                   trial_ids=np.arange(1, 4), metadata=metadata or {}, source="chirp.csv")


def test_the_sidecar_declares_a_linear_input_and_the_likelihood_uses_it(tmp_path):
    from pmabayes.data import read_csv, write_csv
    from pmabayes.likelihood import Likelihood

    ds = _chirp_dataset({"input_between_samples": "linear"}, between="linear")
    write_csv(ds, tmp_path / "lin.csv")
    back = read_csv(tmp_path / "lin.csv")
    assert back.input_between_samples == "linear"
    assert _chirp_dataset().input_between_samples == "hold"
    lik = Likelihood(pb.Model(), back)
    x = lik.simulate(pb.Model().theta({}))
    assert np.array_equal(x, pb.simulate(pb.Model(), {}, back.input[0], time_s=back.time_s,
                                         between_samples="linear"))
    assert max_err(x[0], back.mean_position_m) < 1e-4  # the data's own convention
    held = pb.simulate(pb.Model(), {}, back.input[0], time_s=back.time_s)[0]
    assert max_err(held, back.mean_position_m) > max_err(x[0], back.mean_position_m) + 5e-5


@pytest.mark.parametrize(("metadata", "pattern"), [
    ({"input_between_sample": "linear"},
     r"chirp.csv: metadata key 'input_between_sample' looks like a misspelling of "
     r"'input_between_samples'.*rename it"),
    ({"sample_rate": 1000.0}, r"misspelling of 'sample_rate_hz'"),
    ({"input_between_samples": "bandlimited"},
     r"'input_between_samples' is 'bandlimited'; it must be one of 'hold', 'linear'"),
    ({"input_between_samples": "zoh"}, r"it must be one of 'hold', 'linear'"),
])
def test_bad_declarations_are_errors_that_name_the_fix(metadata, pattern):
    from pmabayes.data import DataError

    with pytest.raises(DataError, match=pattern):
        _chirp_dataset(metadata)


def test_free_form_metadata_stays_allowed():
    ds = _chirp_dataset({"operator": "A. N. Other", "valve_model": "171E2N",
                         "generator_version": 3})
    assert ds.metadata["operator"] == "A. N. Other"


def _periodic_dataset(metadata, n_periods=3, period=500):
    from pmabayes.data import Dataset

    t = np.arange(n_periods * period) * 1e-3
    p = 3e5 + 1.5e5 * np.sin(2 * np.pi * t / (period * 1e-3))
    x = 1e-3 * np.sin(2 * np.pi * t / (period * 1e-3))[None]
    return Dataset(time_s=t, input=p[None], position_m=x, trial_ids=np.array([1]),
                   metadata=metadata, source="sine.csv")


def test_a_declared_period_is_read_from_the_sidecar(tmp_path):
    from pmabayes.data import read_csv, write_csv

    ds = _periodic_dataset({"period_samples": 500, "starts_in_steady_state": True})
    write_csv(ds, tmp_path / "sine.csv")
    back = read_csv(tmp_path / "sine.csv")
    assert (back.period_samples, back.n_periods, back.starts_in_steady_state) == (500, 3, True)
    plain = _periodic_dataset({})
    assert (plain.period_samples, plain.n_periods, plain.starts_in_steady_state) == (
        None, None, False)


@pytest.mark.parametrize(("metadata", "pattern"), [
    ({"period_samples": 400},
     r"sine.csv: metadata 'period_samples' is 400, which does not divide the record's 1500 "
     r"samples.*trim the record to 1200 samples"),
    ({"period_samples": 2000, "starts_in_steady_state": True},
     r"sine.csv: .*'period_samples' is 2000 but the record starts in steady state, and is "
     r"only 1500 samples long, shorter than one period"),
    ({"period_samples": 500.0}, r"'period_samples' is 500.0; it must be a whole number"),
    ({"period_samples": 1}, r"at least 2"),
    ({"starts_in_steady_state": True},
     r"'starts_in_steady_state' is true but no 'period_samples' is declared"),
    ({"period_samples": 500, "starts_in_steady_state": "yes"}, r"true or false"),
    ({"period_sample": 500}, r"'period_sample' looks like a misspelling of 'period_samples'"),
])
def test_bad_period_declarations_are_errors_that_name_the_fix(metadata, pattern):
    from pmabayes.data import DataError

    with pytest.raises(DataError, match=pattern):
        _periodic_dataset(metadata)
