"""The proof on real measurements: the bugs the real records found, each with a
fast test, and the two analyses run end to end on ``../shared/external/real`` (slow;
skipped when that folder is not beside the checkout).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pmabayes.criticism.diagnosis import _experiments
from pmabayes.criticism.elpd import laplace_loo
from pmabayes.data import Dataset
from pmabayes.inference import FitError, build_posterior, find_map, search
from pmabayes.model import Model, Rig
from pmabayes.synthetic import Chirp, generate_chirp_dataset

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "external" / "real"


def _rc_column_like(n: int = 600) -> Dataset:
    """A record on the RC column chiu's scale: 185 kN on 1360 kg, 20 mm of motion."""
    t = np.arange(n) * 0.02
    force = 1.85e5 * np.sin(2 * np.pi * t / 4.0) * (1 + t / t[-1])
    x = force / 1.0e7 + 1e-3 * np.sin(2 * np.pi * t / 4.0 - 0.3)
    rig = {"name": "chiu", "input_kind": "force", "moving_mass_kg": 1360.0,
           "gravity_sign": 0.0, "area_m2": 1.0, "g_m_s2": 9.81}
    return Dataset(time_s=t, input=force[None], position_m=x[None], trial_ids=np.array([1]),
                   input_name="force_n", metadata={"rig": rig}, source="chiu.csv")


def test_diagnose_puts_a_force_rigs_default_priors_on_the_data_scale():
    """diagnose fitted a force-input rig under the muscle's priors (alpha ~ 25 N/m against
    1e7 N/m here), where nothing simulated: the RC column chiu crashed it."""
    ds = _rc_column_like()
    models = _experiments(ds, None, ())[1]
    fitted = build_posterior(Model.for_dataset(ds), ds, substeps=1)
    for name in ("alpha", "K_e", "d"):
        assert models[0].chosen_priors()[name] == fitted.priors[fitted.names.index(name)]
    assert models[0].chosen_priors()["alpha"].median > 1e5
    # a user's prior still wins
    mine = Model(rig=Rig.from_dict(ds.metadata["rig"]), priors={"alpha": fitted.priors[0]})
    assert _experiments(ds, mine, ())[1][0].chosen_priors()["alpha"] == fitted.priors[0]


def test_a_search_that_ends_where_nothing_simulates_is_a_fit_error(monkeypatch):
    """The MAP's output was None there (x[0] of None: a TypeError); now one clear error."""
    ds = generate_chirp_dataset(n_trials=2, chirp=Chirp(duration_s=1.0))
    posterior = build_posterior(Model.for_dataset(ds), ds, substeps=1)
    n_model = posterior.n_model

    def nowhere(post, z0, scale):
        return np.full_like(z0, np.nan), np.eye(z0.size), None

    monkeypatch.setattr(search, "_global_search",
                        lambda post, box, *a: (np.zeros(n_model), 1.0))
    monkeypatch.setattr(search, "_polish_from", nowhere)
    monkeypatch.setattr(search, "_climb", lambda post, z, cov, note, scale, rng: (z, cov, note))
    with pytest.raises(FitError, match="found no point where the model simulates the data "
                                       "under its priors .*not a number.*--prior"):
        find_map(posterior, rng=np.random.default_rng(0), refer=False)


def test_the_elpd_of_too_few_usable_draws_is_unknown_not_a_crash():
    """PSIS-LOO raised (arviz: "n_draws_tail must be at least 5") when few Laplace draws
    had a finite likelihood, as on the RC column chiu: now the ELPD is NaN."""
    ds = generate_chirp_dataset(n_trials=2, chirp=Chirp(duration_s=1.0))
    posterior = build_posterior(Model.for_dataset(ds), ds, substeps=1)
    lik = posterior.likelihoods[0]
    pointwise = lik.pointwise

    def few(x, *noise):
        out = np.array(pointwise(x, *noise), dtype=float)
        out[3:] = np.nan  # the simulation fails for all but three draws
        return out

    lik.pointwise = few
    n = len(posterior.names)
    best = SimpleNamespace(z=np.zeros(n), covariance_z=1e-6 * np.eye(n))
    loo = laplace_loo(posterior, best, np.random.default_rng(0), 40, 0.9, ("alpha",))
    assert np.isnan(loo.elpd) and loo.elpd_i.shape == (2,) and np.isnan(loo.elpd_i).all()
    assert np.isnan(loo.interval["alpha"]).all()
    assert not loo.reliable and "Laplace draws are inside" in loo.note
    lik.pointwise = pointwise  # with every draw usable it is a number
    assert np.isfinite(laplace_loo(posterior, best, np.random.default_rng(0), 40, 0.9).elpd)


def _run(script: str, out: Path) -> str:
    done = subprocess.run([sys.executable, str(ROOT / "analyses" / script), "--quick",
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                          check=False)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout


@pytest.mark.slow
@pytest.mark.skipif(not (REAL / "cavatappi").is_dir(),
                    reason=f"{REAL / 'cavatappi'} is not there (the real data beside the checkout)")
def test_the_real_cavatappi_loop_runs_end_to_end(tmp_path):
    said = _run("real_cavatappi.py", tmp_path / "out")
    assert "held-out loads" in said and "sample1_200g" in said and "sample1_400g" in said
    assert (tmp_path / "out" / "table.csv").is_file()
    assert not list(ROOT.glob("sample1_*g.json"))  # nothing written beside the data or here


@pytest.mark.slow
@pytest.mark.skipif(not (REAL / "rc_columns").is_dir(),
                    reason=f"{REAL / 'rc_columns'} is not there (the real data beside the "
                           "checkout)")
def test_the_real_rc_columns_run_end_to_end(tmp_path):
    said = _run("real_rc_columns.py", tmp_path / "out")
    assert "kN and N give the same NRMSE (within 0.1%) on every specimen: True" in said
