"""
Validation on held-out data
===========================

A fit is only as good as its predictions of experiments it has not seen.
:func:`pmabayes.validate` simulates the posterior on the input of each held-out
experiment, on that experiment's own rig, and compares with what was measured:
the error against the noise floor, and how many measurements fall inside the
predictive band. Everything here is **synthetic**: short chirps of the paper's
model to fit, then held-out steps and a sine on the loaded control rig, and a
chirp of the lab-like plant (a 45 ms lag and 0.8 N of friction the model lacks).
"""

# %%
# Fit
# ---
# Four 5 s chirps of the paper's model. The sampler's budget is small here to
# keep the page quick.
from dataclasses import replace

import matplotlib.pyplot as plt
import numpy as np

import pmabayes as pb
from pmabayes.data import Dataset
from pmabayes.inference import FitSettings
from pmabayes.synthetic import Chirp, MeasurementNoise, generate_chirp_dataset

train = generate_chirp_dataset(n_trials=4, seed=1, chirp=Chirp(duration_s=5.0))
tree = pb.fit(train, pb.Model(), settings=FitSettings(max_steps=600, n_walkers=16))

# %%
# Held-out experiments
# --------------------
# 8 s of pressure steps (unloaded) and of a 1 Hz sine on the 500 g control rig,
# 5 trials each, made by the paper's model with the default measurement noise;
# and a chirp from the lab-like plant, which the fitted model cannot describe.
t = np.arange(8000) / 1000.0
steps = np.repeat([0.0, 0.15, 0.4, 0.25, 0.1, 0.45, 0.3, 0.05], 1000) * 1e6
sine = 0.3e6 + 0.15e6 * np.sin(2 * np.pi * 1.0 * t)
rng = np.random.default_rng(10)
held = []
for name, p, rig in (("steps", steps, pb.Rig.characterisation()),
                     ("sine_loaded", sine, pb.Rig.control())):
    x = pb.simulate(pb.Model(rig=rig), None, p, time_s=t)  # the paper's values
    y = MeasurementNoise().apply(np.repeat(x, 5, axis=0), 1e-3, rng)
    held.append(Dataset(t, np.repeat(p[None], 5, axis=0), y, np.arange(1, 6),
                        metadata={"synthetic": True, "rig": rig.to_dict()}, source=name))
lab = generate_chirp_dataset(n_trials=5, seed=9, chirp=Chirp(duration_s=8.0),
                             effects={"regulator_lag": 0.045, "coulomb_friction": 0.8})
held.append(replace(lab, source="lab_chirp"))

# %%
# Validate
# --------
v = pb.validate(tree, held, n_draws=100)
for e in v.experiments:
    floor = e.noise_floor_m
    ratio = f"{e.rmse_m / floor:.2f}x the floor" if floor and np.isfinite(floor) else "no floor"
    print(f"{e.name:12s} {e.rig['name'] if isinstance(e.rig, dict) else e.rig!s:18s} "
          f"RMSE {e.rmse_m * 1e6:8.1f} µm ({ratio}); "
          f"{100 * e.band_coverage:.1f}% inside the 90% band")

# %%
# The right model predicts the new inputs, on both rigs, within a small multiple
# of their noise floors (four short chirps pin its parameters less well than the
# ten long ones of :doc:`../guide/validation`), and its band holds most of the
# measurements; the model that lacks the lag and the friction is hundreds of
# times above the floor, and its band holds few. The loaded sine's trials and
# band, about the posterior-mean prediction (on the scale of the motion, 60 mm,
# the band is thinner than the line):
e = v.experiments[1]
fig, ax = plt.subplots(figsize=(8, 3.5), layout="constrained")
ax.fill_between(e.time_s, (e.low_m - e.prediction_m) * 1e6, (e.high_m - e.prediction_m) * 1e6,
                color="tab:blue", alpha=0.3, label="90% predictive band")
ax.plot(e.time_s, (e.position_m - e.prediction_m).T * 1e6, "k.", ms=0.5)
ax.set(xlim=(2, 4), xlabel="time [s]", ylabel="measured - predicted [µm]",
       title="held-out sine, loaded rig: trials and band about the prediction")
ax.legend(loc="upper right")
plt.show()
