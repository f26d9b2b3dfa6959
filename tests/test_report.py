"""Tests of the report stage on a small, realistic fake fit written to and read from NetCDF."""

from __future__ import annotations

import base64
import csv
import json
import re

import arviz as az
import numpy as np
import pytest
import xarray as xr
from conftest import _ar1, fake_fit

from pmabayes.data import Dataset
from pmabayes.inference.fitfile import fit_info, load_fit, save_fit
from pmabayes.model.model import PAPER_VALUES
from pmabayes.report.fit_page import write_report
from pmabayes.report.summary import SUMMARY_COLUMNS, summary_table, write_summary

PARAMS = {  # name: (unit, posterior mean, posterior sd)
    "alpha": ("N/m", 24.1, 0.6),
    "beta": ("1/m", 2.1, 0.3),
    "gamma": ("1/m", -35.0, 1.5),  # the paper's -42.6 is off the pair plot's scale
    "d": ("N s/m", 152.0, 3.0),
    "K_e": ("N/m", 630.0, 5.0),
    "p_dz": ("Pa", 67.4e3, 400.0),
    "tau_reg": ("s", 0.045, 0.002),
    "sigma_noise_m": ("m", 2.2e-5, 1e-6),
    "rho_noise": ("1", 0.93, 0.01),
}
FIGURES = ("trace.png", "rank.png", "pair.png", "ppc.png", "residual.png")


#: the report's fake fit: PARAMS with a regulator lag (conftest.fake_fit)
FIT = {"params": PARAMS, "effects": ["regulator_lag"], "n_chain": 8, "n_draw": 100}


def _dataset_of(tree: xr.DataTree, source: str) -> Dataset:
    obs = tree["observed_data"]["position_m"]
    p = tree["constant_data"]["pressure_pa"].values
    return Dataset(
        time_s=obs["time"].values,
        input=np.tile(p, (obs.sizes["trial"], 1)),
        position_m=obs.values,
        trial_ids=obs["trial"].values,
        metadata={"synthetic": True},
        source=source,
    )


@pytest.fixture(scope="module")
def bad_fit(tmp_path_factory):
    """The fake fit (not converged, synthetic data), read back from NetCDF."""
    path = save_fit(fake_fit(**FIT, converged=False, seed=1),
                    tmp_path_factory.mktemp("fit") / "fit.nc")
    return load_fit(path)


@pytest.fixture(scope="module")
def bad_report(bad_fit, tmp_path_factory):
    out = tmp_path_factory.mktemp("report_bad")
    return write_report(bad_fit, out)


@pytest.fixture(scope="module")
def good_report(tmp_path_factory):
    """Converged, non-synthetic, reported with its matching data set."""
    tree = fake_fit(**FIT, converged=True, synthetic=False, seed=2)
    tree = load_fit(save_fit(tree, tmp_path_factory.mktemp("fit") / "good.nc"))
    out = tmp_path_factory.mktemp("report_good")
    return write_report(tree, out, dataset=_dataset_of(tree, "lab/run_42.csv"))


# ----------------------------------------------------------------------------- table


def test_summary_rows_match_numpy_and_fit_info(bad_fit):
    info = fit_info(bad_fit)
    rows = summary_table(bad_fit)
    assert [r["name"] for r in rows] == list(PARAMS)
    rhat = az.rhat(bad_fit, sample_dims=["chain", "draw"])  # the posterior node
    ess_bulk = az.ess(bad_fit, sample_dims=["chain", "draw"])
    for r in rows:
        x = bad_fit["posterior"][r["name"]].values
        assert set(r) == set(SUMMARY_COLUMNS)
        assert r["unit"] == PARAMS[r["name"]][0]
        np.testing.assert_allclose(r["mean"], x.mean(), rtol=1e-12)
        np.testing.assert_allclose(r["sd"], x.std(ddof=1), rtol=1e-12)
        np.testing.assert_allclose(r["r_hat"], float(rhat[r["name"]]), rtol=1e-12)
        np.testing.assert_allclose(r["ess_bulk"], float(ess_bulk[r["name"]]), rtol=1e-12)
        conv = info["convergence"]
        assert r["ess"] == conv["ess"][r["name"]]
        assert r["tau"] == conv["tau"][r["name"]]
        assert r["r_hat_ensembles"] == conv["rhat_ensembles"][r["name"]]
        assert r["map"] == info["map"]["values"][r["name"]]
        assert r["paper"] == PAPER_VALUES.get(r["name"])
        assert r["ci_prob"] == 0.9
    assert sum(r["paper"] is not None for r in rows) == len(PAPER_VALUES)
    assert rows[-1]["global_search"] is None and rows[0]["global_search"] is not None


def test_summary_hdi_is_90_percent_hdi(bad_fit):
    rows = {r["name"]: r for r in summary_table(bad_fit)}
    hdi90 = az.hdi(bad_fit, prob=0.9)
    default = az.summary(bad_fit, fmt="xarray", round_to="none")  # ArviZ default: 89% ETI
    assert "eti89_lb" in default["summary"].values
    for name, r in rows.items():
        lo, hi = (float(v) for v in hdi90[name].values)
        assert (r["hdi_low"], r["hdi_high"]) == (lo, hi)
        x = bad_fit["posterior"][name].values.ravel()
        inside = np.mean((x >= lo) & (x <= hi))
        assert abs(inside - 0.9) <= 2 / x.size
        eti = default[name].sel(summary=["eti89_lb", "eti89_ub"]).values
        assert not np.allclose(eti, [lo, hi], rtol=0, atol=1e-12)
    narrow = {r["name"]: r for r in summary_table(bad_fit, ci_prob=0.5)}
    for name, r in rows.items():
        assert narrow[name]["hdi_high"] - narrow[name]["hdi_low"] < r["hdi_high"] - r["hdi_low"]


def test_summary_rejects_bad_arguments(bad_fit):
    with pytest.raises(ValueError, match="ci_prob"):
        summary_table(bad_fit, ci_prob=90)
    with pytest.raises(TypeError):
        summary_table(bad_fit, hdi_prob=0.9)  # unknown keyword
    with pytest.raises(TypeError):
        write_report(bad_fit, "unused", data=None)  # unknown keyword


def test_write_summary_csv_and_markdown(bad_fit, tmp_path):
    rows = summary_table(bad_fit)
    csv_path, md_path = write_summary(rows, tmp_path / "out")
    with csv_path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == SUMMARY_COLUMNS
        back = list(reader)
    assert len(back) == len(rows)
    for r, b in zip(rows, back, strict=True):
        assert b["name"] == r["name"] and b["unit"] == r["unit"]
        for key in ("mean", "sd", "hdi_low", "hdi_high", "r_hat", "ess", "ess_bulk", "map"):
            assert float(b[key]) == r[key]  # full precision
        assert b["paper"] == ("" if r["paper"] is None else repr(r["paper"]))

    lines = md_path.read_text(encoding="utf-8").splitlines()
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header[:6] == ["parameter", "unit (SI)", "mean", "sd", "90% HDI low",
                          "90% HDI high"]
    assert "paper" in header and "MAP (global search)" in header and "ESS bulk" in header
    assert "highest-density draw" in header
    assert re.fullmatch(r"\|(-{3}:?\|)+", lines[1].replace("---:", "---").replace(
        "|---|", "|---|"))
    assert len(lines) == 2 + len(rows)
    for r, line in zip(rows, lines[2:], strict=True):
        cells = dict(zip(header, (c.strip() for c in line.strip("|").split("|")),
                         strict=True))
        assert cells["parameter"] == f"`{r['name']}`"
        assert cells["unit (SI)"] == r["unit"]
        assert cells["mean"] == f"{r['mean']:.4g}"
        assert float(cells["90% HDI low"]) == float(f"{r['hdi_low']:.4g}")
        assert cells["paper"] == ("\u2014" if r["paper"] is None else f"{r['paper']:.4g}")
        assert cells["MAP (global search)"] == f"{r['map']:.4g}"


# ----------------------------------------------------------------------------- report


def _html(index):
    return index.read_text(encoding="utf-8")


def test_report_writes_every_file(bad_report):
    out = bad_report.parent
    assert bad_report.name == "index.html"
    for name in ("summary.csv", "summary.md", *FIGURES):
        assert (out / name).stat().st_size > 1000 or name.startswith("summary")
    for name in FIGURES:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_html_is_self_contained(bad_report):
    text = _html(bad_report)
    assert "http://" not in text and "https://" not in text
    assert "<script" not in text.lower() and "<link" not in text.lower()
    assert "@import" not in text and "url(" not in text
    sources = re.findall(r'src="([^"]*)"', text)
    assert len(sources) == len(FIGURES)
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    # every figure file is embedded byte for byte
    embedded = {base64.b64decode(s.split(",", 1)[1]) for s in sources}
    assert embedded == {(bad_report.parent / f).read_bytes() for f in FIGURES}


def test_report_html_content_not_converged(bad_report, bad_fit):
    text = _html(bad_report)
    for name in PARAMS:
        assert f"<td>{name}</td>" in text
    for unit in ("N s/m", "Pa", "1/m"):
        assert f"<td>{unit}</td>" in text
    assert "NOT CONVERGED" in text
    for message in fit_info(bad_fit)["convergence"]["messages"]:
        assert message.replace(">", "&gt;").replace("<", "&lt;") in text
    assert "Synthetic data" in text
    assert "pma_chirp_fake.csv" in text
    assert "31 µm" in text and "29 µm" in text  # MAP and global-search RMS costs
    floor = fit_info(bad_fit)["data"]["noise_floor_m"]
    assert f"{floor * 1e6:.3g} µm" in text
    assert "90% HDI low" in text
    assert "24.16" in text  # MAP of alpha
    assert "23.7" in text  # paper's alpha (%.4g)


@pytest.mark.slow
def test_report_html_content_converged(good_report):
    text = _html(good_report)
    assert "NOT CONVERGED" not in text and "not-converged" not in text
    assert 'class="banner ok"' in text
    assert "Synthetic data" not in text
    assert "run_42.csv" in text  # the data set's source names the report
    assert text.count("data:image/png;base64,") == len(FIGURES)


def test_report_dataset_mismatch(bad_fit, tmp_path):
    ds = _dataset_of(bad_fit, "lab/other.csv")
    changed = ds.position_m.copy()
    changed[1, 7] += 1e-9
    wrong_values = Dataset(time_s=ds.time_s, input=ds.input, position_m=changed,
                           trial_ids=ds.trial_ids, source="lab/other.csv")
    with pytest.raises(ValueError, match=r"lab/other\.csv.*pma_chirp_fake\.csv"):
        write_report(bad_fit, tmp_path / "a", dataset=wrong_values)
    with pytest.raises(ValueError, match=r"lab/other\.csv.*shape"):
        write_report(bad_fit, tmp_path / "b", dataset=ds.select_trials([0, 1]))
    shifted = Dataset(time_s=ds.time_s + 0.5, input=ds.input, position_m=ds.position_m,
                      trial_ids=ds.trial_ids, source="lab/other.csv")
    with pytest.raises(ValueError, match=r"lab/other\.csv.*sample times"):
        write_report(bad_fit, tmp_path / "c", dataset=shifted)
    assert not any((tmp_path / d).exists() for d in "abc")


def test_predictive_quantiles_blockwise(monkeypatch):
    import pmabayes.report.fit_data as report

    rng = np.random.default_rng(3)
    da = xr.DataArray(rng.normal(size=(1, 6, 3, 101)).astype(np.float32),
                      dims=("chain", "draw", "trial", "time"))
    monkeypatch.setattr(report, "_QUANTILE_BLOCK", 18 * 7)  # blocks of 7 samples
    got = report._quantiles_over_samples(da, [0.05, 0.5, 0.95])
    want = np.quantile(da.values.reshape(18, 101), [0.05, 0.5, 0.95], axis=0)
    np.testing.assert_allclose(got, want, rtol=1e-6)


@pytest.mark.slow
def test_arviz_plot_failure_falls_back_to_matplotlib(bad_fit, tmp_path, monkeypatch):
    import arviz as az
    import matplotlib.pyplot as plt

    import pmabayes.report.figures as plots

    def boom(*args, **kwargs):
        plt.figure()  # a half-made figure must not leak
        raise RuntimeError("simulated ArviZ failure")

    monkeypatch.setattr(az, "plot_trace_dist", boom)
    monkeypatch.setattr(az, "plot_rank", boom)
    before = plt.get_fignums()
    note = plots.plot_trace(bad_fit, tmp_path / "t.png", units={"sigma_noise_m": "m"})
    assert "fallback" in note and "simulated ArviZ failure" in note
    factor, note = plots.plot_rank(bad_fit, tmp_path / "r.png")
    assert factor == 1 and "fallback" in note
    assert plt.get_fignums() == before
    for name in ("t.png", "r.png"):
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"


# ----------------------------------------------------------------------------- adequacy
# "Sampling converged" is not "the model fits": every report opens with the verdict.


def _fit_of(dataset: Dataset, model_m: np.ndarray, seed: int = 0) -> xr.DataTree:
    """A converged fake fit of ``dataset`` whose posterior predictive model is ``model_m``.

    The noise is identified from the data as ``pmabayes fit`` does; the predictive draws
    are the model plus that noise, so only the model decides whether the data fit.
    """
    from pmabayes.inference.likelihood import Likelihood
    from pmabayes.inference.noise import estimate_noise
    from pmabayes.model.model import Model

    rng = np.random.default_rng(seed)
    noise = estimate_noise(Likelihood(Model(), dataset))
    n_trial, n_time = dataset.position_m.shape
    tree = fake_fit(**FIT, n_trial=n_trial, n_time=n_time, dt_s=dataset.dt_s,
                    converged=True, seed=seed)
    n_pp = 12
    model_pp = np.repeat(model_m[None], n_pp, axis=0)
    pred = model_pp[:, None, :] + _ar1(rng, (n_pp, n_trial, n_time), noise.sigma, noise.rho)
    coords = {"trial": dataset.trial_ids, "time": dataset.time_s}
    tree["observed_data"] = xr.DataTree(xr.Dataset(
        {"position_m": (("trial", "time"), dataset.position_m)}, coords=coords))
    tree["constant_data"] = xr.DataTree(xr.Dataset(
        {"pressure_pa": (("time",), dataset.input[0])}, coords={"time": dataset.time_s}))
    tree["posterior_predictive"] = xr.DataTree(xr.Dataset(
        {"position_m": (("chain", "draw", "trial", "time"), pred[None].astype(np.float32)),
         "model_position_m": (("chain", "draw", "time"), model_pp[None].astype(np.float32))},
        coords={"chain": [0], "draw": np.arange(n_pp), **coords}))
    info = json.loads(tree.attrs["pmabayes"])
    info["model"]["effects"] = []
    info["model"]["rig"] = None
    info["noise"].update(sigma_noise_m=noise.sigma, rho_noise=noise.rho,
                         sigma_white_m=noise.white)
    info["data"].update(source=dataset.source, noise_floor_m=dataset.noise_floor_m,
                        synthetic=True)
    tree.attrs["pmabayes"] = json.dumps(info)
    return tree


def _chirp_data(effects, source: str, seed: int):
    """Chirp trials from the paper's model (with ``effects`` hidden) and the base model."""
    from dataclasses import replace

    import pmabayes as pb
    from pmabayes.synthetic import Chirp, generate_chirp_dataset

    ds = generate_chirp_dataset(n_trials=4, seed=seed, effects=effects,
                                chirp=Chirp(duration_s=4.0, f0_hz=0.3, f1_hz=2.0))
    ds = replace(ds, source=source)
    base = pb.simulate(pb.Model(), {}, ds.input[0], time_s=ds.time_s)[0]
    return ds, base


@pytest.fixture(scope="module")
def hidden_lag(tmp_path_factory):
    """The base model's report on data with a hidden 45 ms regulator lag."""
    ds, base = _chirp_data({"regulator_lag": 0.045}, "data/hidden_lag.csv", seed=31)
    tree = load_fit(save_fit(_fit_of(ds, base), tmp_path_factory.mktemp("fit") / "lag.nc"))
    index = write_report(tree, tmp_path_factory.mktemp("report_lag"), dataset=ds)
    return ds, base, tree, index


@pytest.fixture(scope="module")
def no_hidden(tmp_path_factory):
    """The base model's report on data from the base model itself."""
    ds, base = _chirp_data(None, "data/no_hidden.csv", seed=32)
    tree = load_fit(save_fit(_fit_of(ds, base), tmp_path_factory.mktemp("fit") / "ok.nc"))
    index = write_report(tree, tmp_path_factory.mktemp("report_ok"), dataset=ds)
    return ds, base, tree, index


def _ratio_in(text: str) -> float:
    match = re.search(r"the error of the trial mean is ([0-9.e+]+)x the noise floor", text)
    assert match, "no error-to-floor ratio in the verdict"
    return float(match.group(1))


def test_a_wrong_model_is_called_inadequate_first_with_the_next_command(hidden_lag):
    from pmabayes.report.verdicts import fit_adequacy

    ds, base, tree, index = hidden_lag
    text = _html(index)
    # the verdict comes first: before the convergence banner and every table
    assert 'class="verdict bad"' in text and "MODEL INADEQUATE" in text
    assert text.index('id="adequacy"') < text.index('class="banner ok"') < text.index("<table")
    # the ratio quoted is the data's: RMS of trial mean minus model over the noise floor
    ratio = np.sqrt(np.mean((ds.mean_position_m - base) ** 2)) / ds.noise_floor_m
    assert ratio > 20
    assert _ratio_in(text) == pytest.approx(ratio, rel=0.01)
    assert "pmabayes diagnose data/hidden_lag.csv" in text
    md = (index.parent / "summary.md").read_text(encoding="utf-8")
    assert "**MODEL INADEQUATE**" in md and "`pmabayes diagnose data/hidden_lag.csv`" in md
    assert _ratio_in(md) == pytest.approx(ratio, rel=0.01)
    # the same verdict for the command line
    verdict = fit_adequacy(tree, dataset=ds)
    assert verdict.adequate is False and verdict.energy > 2.0
    assert verdict.ratio == pytest.approx(ratio, rel=0.01)
    lines = verdict.lines()
    assert lines[0].startswith("MODEL INADEQUATE") and "noise floor" in lines[0]
    assert lines[-1] == "Next: pmabayes diagnose data/hidden_lag.csv"
    assert "inside the 90% posterior predictive band" in lines[0]


def test_a_right_model_is_called_adequate(no_hidden):
    from pmabayes.report.verdicts import fit_adequacy

    ds, base, tree, index = no_hidden
    text = _html(index)
    assert 'class="verdict ok"' in text and "Model adequate" in text
    assert "MODEL INADEQUATE" not in text and "pmabayes diagnose" not in text
    ratio = np.sqrt(np.mean((ds.mean_position_m - base) ** 2)) / ds.noise_floor_m
    assert ratio < 1.5 and _ratio_in(text) == pytest.approx(ratio, rel=0.01)
    md = (index.parent / "summary.md").read_text(encoding="utf-8")
    assert "**Model adequate**" in md and "diagnose" not in md
    verdict = fit_adequacy(tree)  # without the data set: rebuilt from the fit
    assert verdict.adequate is True and verdict.energy < 1.1
    assert not any(line.startswith("Next:") for line in verdict.lines())
    assert verdict.noise_model == "AR(1) + white"  # the repeats support it
    # the check of the trials, in one line
    assert f"Trials: {ds.n_trials} exchangeable" in text


def test_the_report_line_says_when_the_trials_drift():
    from pmabayes.report.fit_page import _trials_line

    rng = np.random.default_rng(5)
    t = np.arange(3000) * 1e-3
    u = 3e5 * (1 + np.sin(2 * np.pi * t))
    y = 1e-9 * u + 1e-5 * rng.standard_normal((8, t.size))
    y += 3e-6 * np.arange(8)[:, None]  # a warm-up: 3 µm more offset per trial
    ds = Dataset(time_s=t, input=np.tile(u, (8, 1)), position_m=y, trial_ids=np.arange(8))
    line = _trials_line(ds)
    assert line.startswith('<p class="note">Trials NOT exchangeable')
    assert "drift with trial order" in line and "µm" in line


def test_the_verdict_names_the_effects_to_diagnose_with(hidden_lag):
    from pmabayes.report.verdicts import fit_adequacy

    ds, _, tree, _ = hidden_lag
    info = json.loads(tree.attrs["pmabayes"])
    info["model"]["effects"] = ["coulomb_friction"]
    tree = tree.copy()
    tree.attrs["pmabayes"] = json.dumps(info)
    lines = fit_adequacy(tree, dataset=ds).lines()
    assert lines[-1] == ("Next: pmabayes diagnose data/hidden_lag.csv "
                         "--effects coulomb_friction")


def test_the_data_of_a_joint_fit_with_gaps_are_recognised(monkeypatch):
    """Samples not observed (NaN in both) do not make a fit's own data look foreign; a
    position that differs, or a sample observed in one and not the other, does."""
    import pmabayes.report.fit_data as fit_data
    from pmabayes.data import DataError, Dataset

    def one(name, seed, gap=True):
        x = np.random.default_rng(seed).normal(size=(1, 50)) * 1e-3
        seen = np.ones((1, 50), dtype=bool)
        if gap:
            seen[0, 10:14] = False
            x[~seen] = np.nan
        return Dataset(time_s=np.arange(50) * 1e-3, input=np.ones((1, 50)), position_m=x,
                       trial_ids=np.arange(1), source=name, observed=seen)

    stored = [one("a.csv", 0), one("b.csv", 1)]
    monkeypatch.setattr(fit_data, "experiment_datasets", lambda tree: stored)
    given = [one("a.csv", 0), one("b.csv", 1)]
    assert fit_data.check_experiment_data(None, given) == given
    with pytest.raises(DataError, match=r"b\.csv does not match .*the samples observed"):
        fit_data.check_experiment_data(None, [one("a.csv", 0), one("b.csv", 1, gap=False)])
    with pytest.raises(DataError, match=r"a\.csv does not match .*the positions"):
        fit_data.check_experiment_data(None, [one("a.csv", 2), one("b.csv", 1)])
