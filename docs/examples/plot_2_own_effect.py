"""
Your own effect: write it, register it, hide it, find it
========================================================

An effect is one small class: its parameters (with units, priors, bounds and the
value at which it vanishes), its physics as a plain Python function, and a
description. Registered, it is usable by name everywhere a built-in effect is:
in a :class:`~pmabayes.model.model.Model`, in synthetic data, and among the
candidates :func:`pmabayes.diagnose` tests. :doc:`../theory/effects` gives the
contract of each stage.

Here: a damping that grows with pressure (a stiffer bladder squeezes the braid
harder), hidden in **synthetic** data, then found.
"""

# %%
# The effect
# ----------
# A force stage effect returns the force that opposes extension and its
# derivatives in position and velocity, which the simulator's implicit step
# needs. ``q`` holds this effect's parameters in declared order. The function
# is compiled with numba when the class is defined.
import matplotlib.pyplot as plt

import pmabayes as pb
from pmabayes.criticism import DiagnoseSettings
from pmabayes.synthetic import Chirp, generate_chirp_dataset


def pressure_damping(q, x, v, p):
    """Force ``b_p p v`` and its derivatives in ``x`` and ``v``."""
    b_p = q[0]
    return b_p * p * v, 0.0, b_p * p


class PressureDamping(pb.Effect):
    """Viscous damping proportional to the pressure (an example user effect)."""

    name = "pressure_damping"
    stage = "force"
    parameters = (
        pb.Parameter("b_p", "N s/(m Pa)", 1e-4, pb.HalfNormal(1e-3), bounds=(0.0, 1.0),
                     null=0.0, description="damping per unit pressure"),
    )
    description = ("Viscous damping that grows with pressure: the bladder presses the "
                   "braid harder. In the residual: an error that follows the velocity, "
                   "larger at high pressure.")
    physics = staticmethod(pressure_damping)


pb.register_effect(PressureDamping)
print([p.name for p in pb.Model(["pressure_damping"]).parameters][-1:])

# %%
# Hide it in synthetic data
# -------------------------
# Four repeated 5 s chirps from the paper's model plus the new effect (a
# quarter more damping at 0.25 MPa), with the default measurement noise.
truth = 2e-4  # N s/(m Pa)
data = generate_chirp_dataset(n_trials=4, seed=3, chirp=Chirp(duration_s=5.0),
                              effects={"pressure_damping": truth})
print(f"synthetic: {data.metadata['synthetic']}, noise floor "
      f"{data.noise_floor_m * 1e6:.1f} µm")

base = pb.Model()
fig, ax = plt.subplots(figsize=(8, 3.5), layout="constrained")
ax.plot(data.time_s, data.mean_position_m * 1e3, "k", lw=1, label="data (trial mean)")
ax.plot(data.time_s, pb.simulate(base, None, data.pressure_pa[0], time_s=data.time_s)[0] * 1e3,
        lw=0.8, label="base model, the paper's values")
ax.set(xlabel="time [s]", ylabel="position [mm]")
ax.legend()
plt.show()

# %%
# Find it
# -------
# The diagnosis does not know what was hidden: the new effect is one candidate
# among others, ranked by the same score test and refitted the same way.
d = pb.diagnose(data, settings=DiagnoseSettings(
    candidates=["pressure_damping", "coulomb_friction", "regulator_lag", "cubic_stiffness"],
    max_refits=2))
print(d.verdict)
for finding in d.ranking:
    print(f"{finding.effect:20s} evidence {finding.evidence:10.3g}  "
          f"significant: {finding.significant}")

# %%
# The refit's estimate, with its 90% interval, against the value hidden:
named = next(f for f in d.ranking if f.effect == "pressure_damping")
lo, hi = named.interval["b_p"]
print(f"b_p = {named.estimate['b_p']:.3g} N s/(m Pa) (90% interval {lo:.3g} to {hi:.3g}); "
      f"hidden: {truth:g}")
