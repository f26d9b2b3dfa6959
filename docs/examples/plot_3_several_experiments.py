"""
Several experiments: one muscle, two rigs
=========================================

An unloaded characterisation chirp and a sine on the loaded control rig (500 g,
gravity toward extension) are two experiments of one muscle: the physical
parameters are shared, while each experiment keeps its own input, trials, rig and
noise. :func:`pmabayes.diagnose` and :func:`pmabayes.fit` take a list of data
sets and treat them so. Both experiments here are **synthetic**, made with a
45 ms regulator lag that the base model lacks.
"""

# %%
# Two experiments
# ---------------
# A 4 s chirp (4 trials) on the characterisation rig and three periods of a
# 1 Hz sine (3 trials) on the control rig. A chirp whose start and end
# frequencies are equal is a sine.
from dataclasses import replace

import matplotlib.pyplot as plt
import numpy as np

import pmabayes as pb
from pmabayes.criticism import DiagnoseSettings
from pmabayes.inference import FitSettings
from pmabayes.synthetic import Chirp, generate_chirp_dataset

lag = {"regulator_lag": 0.045}
chirp = generate_chirp_dataset(n_trials=4, seed=11, chirp=Chirp(duration_s=4.0), effects=lag,
                               description="chirp_unloaded")
sine = generate_chirp_dataset(
    n_trials=3, seed=12, rig=pb.Rig.control(), effects=lag,
    chirp=Chirp(f0_hz=1.0, f1_hz=1.0, duration_s=3.0, p_min_pa=0.1e6, p_max_pa=0.45e6),
    description="sine_loaded")
# an experiment is named after its source (a file's stem)
experiments = [replace(chirp, source="chirp_unloaded"), replace(sine, source="sine_loaded")]

fig, axes = plt.subplots(1, 2, figsize=(9, 3.2), layout="constrained")
for ax, data, title in zip(axes, experiments, ("chirp, unloaded", "sine, 500 g load"),
                           strict=True):
    ax.plot(data.time_s, data.position_m.T * 1e3, lw=0.6)
    ax.set(title=f"{title} (synthetic)", xlabel="time [s]", ylabel="position [mm]")
plt.show()

# %%
# Diagnose them together
# ----------------------
# One MAP of the shared parameters, a verdict per experiment, one score test
# with both experiments' scores added, and refits over both.
d = pb.diagnose(experiments, settings=DiagnoseSettings(
    candidates=["regulator_lag", "transport_delay", "coulomb_friction"], max_refits=2))
print(d.verdict)
for e in d.experiments:
    print(f"  {e.name}: RMS {e.rms_m * 1e6:.0f} µm against a floor of "
          f"{e.noise_floor_m * 1e6:.1f} µm; adequate: {e.adequate}")

# %%
# Fit both with the lag
# ---------------------
# The posterior of the shared parameters, and a noise per experiment. The
# sampler's budget is small here (``FitSettings(max_steps=...)``) to keep the
# page quick; a converged run takes the default settings.
tree = pb.fit(experiments, pb.Model(["regulator_lag"]),
              settings=FitSettings(max_steps=600, n_walkers=16))
post = tree["posterior"].to_dataset()
tau = post["tau_reg"].values.ravel()
print(f"tau_reg: mean {tau.mean() * 1e3:.2f} ms, 90% interval "
      f"{np.quantile(tau, 0.05) * 1e3:.2f} to {np.quantile(tau, 0.95) * 1e3:.2f} ms "
      "(45 ms hidden)")
sigma = post["sigma_noise_m"]
for name in sigma["experiment"].values:
    print(f"noise of {name}: {float(sigma.sel(experiment=name).mean()) * 1e6:.1f} µm")

fig, ax = plt.subplots(figsize=(6, 3.2), layout="constrained")
ax.hist(tau * 1e3, bins=40, color="tab:blue")
ax.axvline(45.0, color="k", label="hidden: 45 ms")
ax.set(xlabel="tau_reg [ms]", ylabel="draws", title="posterior of the shared lag")
ax.legend()
plt.show()
