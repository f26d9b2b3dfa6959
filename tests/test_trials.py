"""Exchangeable trials: drift with trial order and outliers are found and named."""

import warnings

import numpy as np
import pytest

from pmabayes.data import DataError, Dataset, save
from pmabayes.inference.likelihood import ar1_noise
from pmabayes.inference.trials import TrialWarning, check_trials, exclude_trials, parse_trial_ids

DT = 1e-3


def trials(seed, *, r=8, n=4000, rho=0.98, sigma_m=1e-5, white_m=2e-6):
    """A 1 mm chirp response repeated ``r`` times with AR(1) + white noise (exchangeable)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    u = np.sin(2 * np.pi * (0.5 * t + 0.2 * t**2))
    y = 1e-3 * u + ar1_noise(r, n, sigma_m, rho, rng) + white_m * rng.standard_normal((r, n))
    return t, u, y


def dataset(t, u, y, ids=None):
    return Dataset(time_s=t, input=np.tile(u, (y.shape[0], 1)), position_m=y,
                   trial_ids=np.arange(y.shape[0]) if ids is None else np.asarray(ids))


def test_exchangeable_trials_pass_and_the_summary_says_so():
    check = check_trials(dataset(*trials(1)))
    assert check.exchangeable and check.flagged == ()
    assert set(check.p_values) == {"offset drift", "shape drift", "outlier"}
    assert all(0 < p <= 1 for p in check.p_values.values())
    assert "8 exchangeable" in check.summary()
    assert check.typical_m == pytest.approx(1e-5 * np.sqrt(8 / 7), rel=0.3)


def test_a_warm_up_offset_growing_with_trial_index_is_a_drift():
    t, u, y = trials(2)
    y = y + 3e-6 * np.arange(8)[:, None]  # 3 µm more per trial: 21 µm over the set
    check = check_trials(dataset(t, u, y, ids=np.arange(10, 18)))
    kinds = {f.kind for f in check.findings}
    assert "offset drift" in kinds, check.summary()
    drift = next(f for f in check.findings if f.kind == "offset drift")
    # the halves of a linear 3 µm/trial drift differ by about 4 x 3 µm
    assert 8e-6 < drift.size_m < 16e-6
    assert set(drift.trial_ids) <= set(range(10, 18))
    assert "drift with trial order" in check.summary() and "µm" in check.summary()


def test_a_mullins_like_softening_of_the_first_trials_names_them():
    t, u, y = trials(3)
    extra = np.array([0.04, 0.015, 0.005, 0, 0, 0, 0, 0])  # the first cycles move further
    y = y + extra[:, None] * 1e-3 * u
    check = check_trials(dataset(t, u, y))
    assert not check.exchangeable
    assert 0 in check.flagged and set(check.flagged) <= {0, 1, 2}, check.summary()


def test_one_bumped_trial_is_an_outlier_with_its_size():
    t, u, y = trials(4)
    y[5] += 1e-4 * np.exp(-0.5 * ((t - 2.0) / 0.2) ** 2)  # a hand on the rig
    check = check_trials(dataset(t, u, y, ids=[3, 4, 5, 6, 7, 8, 9, 11]))
    outliers = [f for f in check.findings if f.kind == "outlier"]
    assert [f.trial_ids for f in outliers] == [(8,)], check.summary()  # id of position 5
    assert outliers[0].multiple > 1.5
    assert outliers[0].size_m == pytest.approx(check.deviation_m[8])
    assert "trial 8 is an outlier" in check.summary()


def test_the_fit_warns_and_names_the_fix():
    t, u, y = trials(5)
    y[2] += 1e-4 * np.exp(-0.5 * ((t - 1.0) / 0.2) ** 2)
    with pytest.warns(TrialWarning, match=r"--exclude-trials 2 "):
        check_trials(dataset(t, u, y), warn=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error", TrialWarning)
        check_trials(dataset(*trials(1)), warn=True)  # exchangeable: no warning


def test_too_few_trials_are_not_tested():
    t, u, y = trials(6, r=2)
    check = check_trials(dataset(t, u, y))
    assert check.exchangeable and all(p is None for p in check.p_values.values())
    assert "too few" in check.summary()
    with pytest.raises(ValueError, match="level"):
        check_trials(dataset(t, u, y), level=1.5)


def test_the_check_is_reproducible():
    ds = dataset(*trials(7))
    assert check_trials(ds, seed=3).p_values == check_trials(ds, seed=3).p_values


@pytest.mark.slow
def test_false_alarm_rate_on_exchangeable_trials_is_at_most_5_percent():
    """AR(1) + white trials, slow and fast disturbances: at most 5% flagged."""
    n_sets, alarms = 0, 0
    for rho in (0.9, 0.98, 0.998):
        for seed in range(20):
            check = check_trials(dataset(*trials(100 + seed, rho=rho)), seed=seed)
            n_sets += 1
            alarms += not check.exchangeable
    assert alarms / n_sets <= 0.05, f"{alarms} of {n_sets}"


def test_exclude_trials_by_id_with_clear_errors():
    ds = dataset(*trials(8, r=4), ids=[3, 5, 7, 9])
    out = exclude_trials(ds, [5, 9])
    assert list(out.trial_ids) == [3, 7] and out.n_trials == 2
    np.testing.assert_array_equal(out.position_m, ds.position_m[[0, 2]])
    with pytest.raises(DataError, match=r"no trial with id 4 .*\[3, 5, 7, 9\]"):
        exclude_trials(ds, [4])
    with pytest.raises(DataError, match="leaves 1 of 4; at least 2"):
        exclude_trials(ds, [3, 5, 7])
    assert parse_trial_ids("3, 7,") == [3, 7]
    with pytest.raises(ValueError, match="'x' is not an integer"):
        parse_trial_ids("3,x")


def test_exclude_trials_on_the_command_line(tmp_path, capsys):
    from pmabayes import cli

    path = tmp_path / "d.csv"
    t, u, y = trials(9, r=4, n=500)
    save(dataset(t, 3e5 * (1 + u), y), path)  # a pressure in Pa
    for command in ("fit", "run", "diagnose"):
        args = cli._parser().parse_args([command, str(path), "--out", str(tmp_path / "o"),
                                         "--exclude-trials", "1,2"])
        ds = (cli._load_all(args)[0] if command != "diagnose"
              else cli._load_data(args, args.data[0], min_trials=2)[0])
        assert list(ds.trial_ids) == [0, 3]
    assert "excluded trials 1,2 of" in capsys.readouterr().out
    args = cli._parser().parse_args(["fit", str(path), "--out", "x", "--exclude-trials", "8"])
    with pytest.raises(DataError, match="no trial with id 8"):
        cli._load_all(args)
    args = cli._parser().parse_args(["fit", str(path), str(path), "--out", "x",
                                     "--exclude-trials", "1"])
    with pytest.raises(cli.CliError, match="names trial ids of one data file"):
        cli._load_all(args)
    args = cli._parser().parse_args(["diagnose", str(path), "--exclude-trials", "0,1,2"])
    with pytest.raises(DataError, match="leaves 1 of 4; at least 2"):
        cli._load_data(args, args.data[0], min_trials=2)
    with pytest.raises(SystemExit):
        cli._parser().parse_args(["fit", str(path), "--out", "x", "--exclude-trials", "a"])
