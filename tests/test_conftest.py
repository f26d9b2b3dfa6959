"""The shared test helpers of ``conftest.py``."""

import numpy as np
from conftest import fake_fit

from pmabayes.inference.fitfile import fit_info, load_fit
from pmabayes.model.model import PAPER_VALUES, Rig


def test_fake_fit_has_the_layout_of_a_fit(tmp_path):
    """The builder itself: groups, names and attributes that the stages read."""
    tree = load_fit(fake_fit(tmp_path / "fit.nc", effects=["regulator_lag"],
                             values={"tau_reg": 0.03}, spread=0.0))
    assert {"posterior", "sample_stats", "observed_data", "posterior_predictive",
            "log_likelihood"} <= set(tree.children)
    info = fit_info(tree)
    assert info["model"]["effects"] == ["regulator_lag"]
    assert Rig.from_dict(info["model"]["rig"]) == Rig.characterisation()
    post = tree["posterior"]
    assert list(post.data_vars) == [*info["model"]["free"], "sigma_noise_m"]
    assert np.all(post["tau_reg"].values == 0.03)  # zero spread: exactly the centre
    wide = fake_fit(spread=0.05, seed=1)["posterior"]
    assert float(wide["K_e"].std()) > 0.02 * PAPER_VALUES["K_e"]
    assert float(np.corrcoef(wide["d"].values.ravel(), wide["K_e"].values.ravel())[0, 1]) > 0.5
