"""The state a trial starts from: at rest under its first input sample (the default) or
at zero position, velocity and hysteresis (a simulation switched on at t = 0, as the
Bouc-Wen benchmark's); declared per experiment in the sidecar as ``initial_state``."""

from __future__ import annotations

import numpy as np
import pytest
from reference_solver import reference_simulate
from test_inputs import OSC_KW, OSC_SUBSTEPS, REQUIREMENT_M, multisine_fn
from test_simulator import BENCH, BENCH_FS, BENCH_MASS, max_err

import pmabayes as pb
from pmabayes.model.simulator import (
    INITIAL_STATES,
    SimulationError,
    _generate,
    simulate_dataset,
    structure_key,
)

OSC = pb.Model(rig=pb.Rig.force_oscillator(BENCH_MASS))


def _multisine(n: int = 1500) -> tuple:
    f = multisine_fn()
    return f, f(np.arange(n) / BENCH_FS)


def test_the_conventions_on_offer():
    assert INITIAL_STATES == ("rest", "zero", "estimate")
    assert pb.data.INITIAL_STATES == INITIAL_STATES


@pytest.mark.parametrize("between", ["hold", "bandlimited"])
def test_zero_state_within_1e5_m_of_the_reference(between, record_property):
    """The benchmark oscillator from x = v = z = 0 under a first force of several tens
    of N, against RK4 started from the same state; the rest start differs from it by
    far more than the requirement, so the test can tell the two apart."""
    f, u = _multisine()
    assert abs(u[0]) > 10.0  # a start at rest would sit u[0] / K_e > 0.2 mm away
    kw = dict(input_fn=f) if between == "bandlimited" else {}
    ref = reference_simulate(u, 1 / BENCH_FS, zero_state=True, **kw, **OSC_KW).position_m
    x = pb.simulate(OSC, BENCH, u, dt_s=1 / BENCH_FS, substeps=OSC_SUBSTEPS,
                    between_samples=between, initial_state="zero")[0]
    rest = pb.simulate(OSC, BENCH, u, dt_s=1 / BENCH_FS, substeps=OSC_SUBSTEPS,
                       between_samples=between)[0]
    err = max_err(x, ref)
    record_property("max_abs_error_m", err)
    assert x[0] == 0.0
    assert err <= REQUIREMENT_M / 5  # measured 5.1e-7 m (hold), 7.1e-7 m (bandlimited)
    assert max_err(rest, ref) > 20 * REQUIREMENT_M  # measured 2.6e-4 m


def test_zero_state_records_zero_states_and_batches_like_one_by_one():
    _, u = _multisine(300)
    batch = {**{k: np.full(3, v) for k, v in BENCH.items()}, "K_e": np.array([4e4, 5e4, 6e4])}
    sim = pb.simulate(OSC, batch, u, dt_s=1 / BENCH_FS, substeps=2, initial_state="zero",
                      states=True)
    assert np.all(sim.position_m[:, 0] == 0.0)
    assert np.all(sim.velocity_m_s[:, 0] == 0.0) and np.all(sim.hysteresis_n[:, 0] == 0.0)
    for b in range(3):
        one = pb.simulate(OSC, {k: v[b] for k, v in batch.items()}, u, dt_s=1 / BENCH_FS,
                          substeps=2, initial_state="zero")[0]
        assert np.array_equal(one, sim.position_m[b])


def test_zero_state_under_a_zero_first_input_is_the_rest_state():
    """With no force at the first sample (and no gravity) rest is x = 0: both agree bit
    for bit, as on the benchmark's sine sweep, which starts at 0 N."""
    _, u = _multisine(600)
    u = u - u[0]
    kw = dict(dt_s=1 / BENCH_FS, substeps=4, between_samples="bandlimited")
    assert np.array_equal(pb.simulate(OSC, BENCH, u, **kw),
                          pb.simulate(OSC, BENCH, u, initial_state="zero", **kw))


def test_the_rest_kernels_are_generated_as_before():
    """Only a zero-state kernel is generated differently (and keyed apart), so the rest
    kernels' source, and their disk cache, do not change."""
    for between in ("hold", "linear", "bandlimited"):
        rest, _ = _generate(OSC, False, True, between)
        assert _generate(OSC, False, True, between, "rest")[0] == rest
        zero, _ = _generate(OSC, False, True, between, "zero")
        assert "initial state" not in rest and "xi = 0.0" in zero and zero != rest
        assert (structure_key(OSC, False, True, between)
                == structure_key(OSC, False, True, between, "rest")
                != structure_key(OSC, False, True, between, "zero"))


def test_steady_state_from_a_zero_start_is_the_same_steady_state():
    """The warm-up starts from the declared state; the oscillator forgets it."""
    _, u = _multisine(750)
    kw = dict(dt_s=1 / BENCH_FS, substeps=4, period_samples=750, steady_state=True)
    assert max_err(pb.simulate(OSC, BENCH, u, **kw)[0],
                   pb.simulate(OSC, BENCH, u, initial_state="zero", **kw)[0]) < 1e-8


def _dataset(metadata: dict):
    from pmabayes.data import Dataset

    _, u = _multisine(600)
    t = np.arange(u.size) / BENCH_FS
    x = pb.simulate(OSC, BENCH, u, dt_s=1 / BENCH_FS, initial_state="zero")
    return Dataset(time_s=t, input=u[None], position_m=x, trial_ids=np.array([1]),
                   input_name="force_n", source="ms.csv",
                   metadata={"rig": OSC.rig.to_dict(), **metadata})


def test_the_sidecar_declares_the_initial_state_and_the_simulation_uses_it(tmp_path):
    from pmabayes.data import load, save

    save(_dataset({"initial_state": "zero"}), tmp_path / "ms.csv")
    back = load(tmp_path / "ms.csv")
    assert back.initial_state == "zero"
    assert _dataset({}).initial_state == "rest"
    x = simulate_dataset(OSC, BENCH, back)
    assert np.array_equal(x, back.position_m)
    assert max_err(simulate_dataset(OSC, BENCH, _dataset({}))[0], back.position_m[0]) > 1e-4


@pytest.mark.parametrize(("metadata", "pattern"), [
    ({"initial_state": "zeros"},
     r"ms.csv: metadata 'initial_state' is 'zeros'; it must be one of 'rest', 'zero'"),
    ({"initial_state": 0}, r"'initial_state' is 0; it must be one of 'rest', 'zero'"),
    ({"initial_sate": "zero"},
     r"ms.csv: metadata key 'initial_sate' looks like a misspelling of 'initial_state'.*"
     r"rename it"),
])
def test_bad_declarations_are_errors_that_name_the_file_and_the_fix(metadata, pattern):
    from pmabayes.data import DataError

    with pytest.raises(DataError, match=pattern):
        _dataset(metadata)


def test_a_bad_argument_names_the_choices():
    with pytest.raises(SimulationError, match=r"initial_state must be one of 'rest', 'zero', "
                                              r"'estimate', got 'origin'"):
        pb.simulate(OSC, BENCH, np.zeros(10), dt_s=1e-3, initial_state="origin")
