"""
The user's loop: see where the model fails, add what is missing
===============================================================

The bundled ``data/pma_chirp_lab.csv`` holds ten repeated pressure chirps of a
**synthetic** lab-like muscle: the paper's model plus a 45 ms regulator lag and
0.8 N of Coulomb friction, which the base model lacks (``data/README.md`` gives
the command that made it). This example runs the loop of
:doc:`../guide/criticism` through the Python API: diagnose the base model, see
where it fails, add the effect the diagnosis names, and diagnose again until the
error reaches the noise floor.

:func:`pmabayes.diagnose` works at the MAP (no sampling), so each step takes
seconds to a minute. To keep this page quick, the candidates are the six effects
of the first library; ``pmabayes diagnose`` on the command line tests every
registered effect, and finds the same two.
"""

# %%
# The data
# --------
# Ten trials of a 15 s chirp from 0.1 to 3 Hz, at 1 kHz. The noise floor is the
# error a perfect model would have: the spread between the trials over
# ``sqrt(R)``.
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import pmabayes as pb
from pmabayes.criticism import DiagnoseSettings
from pmabayes.data import load

# sphinx_gallery_thumbnail_number = 3

root = Path(pb.__file__).resolve().parents[1]
lab = load(root / "data" / "pma_chirp_lab.csv")
print(f"{lab.n_trials} trials x {lab.time_s.size} samples, synthetic: "
      f"{lab.metadata['synthetic']}; noise floor {lab.noise_floor_m * 1e6:.1f} µm")

fig, ax = plt.subplots(figsize=(8, 3.5), layout="constrained")
ax.plot(lab.time_s, lab.position_m.T * 1e3, lw=0.5)
ax.set(xlabel="time [s]", ylabel="position [mm]", title="ten repeated chirps (synthetic)")
plt.show()

# %%
# Diagnose the base model
# -----------------------
# ``diagnose`` fits the model's MAP, compares the error of the trial mean with
# the floor, band by band, ranks the candidate effects by a score test, refits
# the significant ones and names the missing effect.
candidates = ["regulator_lag", "transport_delay", "coulomb_friction", "cubic_stiffness",
              "pressure_stiffness", "position_offset"]
steps = {}
settings = DiagnoseSettings(candidates=candidates, max_refits=2)
steps["base"] = pb.diagnose(lab, settings=settings)
print(steps["base"].verdict)

# %%
# The error grows with frequency and the residual lags the command: the
# signature of a lag. The residual of the trial mean, against the floor:
base = steps["base"]
fig, ax = plt.subplots(figsize=(8, 3.5), layout="constrained")
ax.plot(lab.time_s, base.experiments[0].residual_m * 1e3, lw=0.6, label="trial mean - model")
ax.axhspan(-lab.noise_floor_m * 1e3, lab.noise_floor_m * 1e3, color="k", alpha=0.3,
           label="noise floor")
ax.set(xlabel="time [s]", ylabel="residual [mm]", title="base model")
ax.legend(loc="upper left")
plt.show()

# %%
# Add what it names, and diagnose again
# -------------------------------------
# The verdict names ``regulator_lag``. Added, the next diagnosis names the
# friction; with both, the model is adequate.
effects = []
while steps[list(steps)[-1]].missing is not None:
    effects.append(steps[list(steps)[-1]].missing)
    label = "base + " + " + ".join(effects)
    steps[label] = pb.diagnose(lab, effects=effects, settings=settings)
    print(steps[label].verdict, end="\n\n")

# %%
# Watch the error fall
# --------------------
# The RMS error of the trial mean per frequency band, for each step, beside the
# noise floor (the black ticks).
bands = {label: d.experiments[0].signature.bands for label, d in steps.items()}
first = next(iter(bands.values()))
names = [f"{lo:g}-{hi:g} Hz" for lo, hi in (b.band_hz for b in first[:-1])] + ["all"]
x = np.arange(len(names))
width = 0.8 / len(bands)
fig, ax = plt.subplots(figsize=(9, 4), layout="constrained")
for i, (label, rows) in enumerate(bands.items()):
    ax.bar(x + (i - (len(bands) - 1) / 2) * width, [b.rms_m * 1e6 for b in rows], width,
           label=label)
ax.scatter(x, [b.floor_m * 1e6 for b in first], marker="_", s=600, color="k",
           label="noise floor", zorder=3)
ax.set_yscale("log")
ax.set_xticks(x, names)
ax.set(ylabel="RMS error of the trial mean [µm]", title="the error falls as effects are added")
ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=4)
plt.show()

for label, d in steps.items():
    print(f"{label:45s} RMS {d.rms_m * 1e6:8.1f} µm = {d.rms_m / d.noise_floor_m:6.2f}x "
          f"the floor; adequate: {d.adequate}")

# %%
# The sizes the refits found, with their 90% intervals (Laplace, at the MAP; a
# ``pmabayes fit`` gives the posterior), against the values the data were made
# with: ``tau_reg`` 0.045 s and ``F_c`` 0.8 N.
for d in list(steps.values())[:-1]:
    named = next(f for f in d.ranking if f.effect == d.missing)
    for name, value in named.estimate.items():
        lo, hi = named.interval[name]
        print(f"{d.missing}: {name} = {value:.4g} (90% interval {lo:.4g} to {hi:.4g})")
