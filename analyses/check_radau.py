"""One-off accuracy check of the simulator against scipy's Radau (rtol 1e-10).

Integrates the paper's base model over the 15 s chirp one sample interval at a time
(the input is held within each), which takes about 2.5 minutes, and prints the
maximum position difference to pmabayes as its last line.

Usage: python analyses/check_radau.py
"""

import time

import numpy as np
from scipy.integrate import solve_ivp

import pmabayes as pb


def main() -> None:
    """Run the check and print ``max_abs_error_m: <number>`` last."""
    v = pb.PAPER_VALUES
    al, be, ga, d, k_e, pdz = (v[k] for k in ("alpha", "beta", "gamma", "d", "K_e", "p_dz"))
    rig = pb.Rig.characterisation()
    m, area, weight = rig.moving_mass_kg, rig.area_m2, rig.gravity_force_n
    dt, n = 1e-3, 15000
    t = np.arange(n) * dt
    p = 0.25e6 * (1 - np.cos(2 * np.pi * (0.1 * t + 2.9 / 30 * t * t)))
    y = np.array([(area * max(p[0] - pdz, 0) - weight) / k_e, 0.0, 0.0])
    out = np.empty(n)
    out[0] = y[0]
    start = time.time()
    for k in range(n - 1):
        force = area * max(p[k] - pdz, 0.0) - weight

        def rhs(_, s, force=force):
            x, vel, z = s
            c = be * np.sign(vel * z) + ga
            return [vel, (force - d * vel - k_e * x - z) / m, vel * (al - c * abs(z))]

        y = solve_ivp(rhs, (0, dt), y, method="Radau", rtol=1e-10, atol=1e-13).y[:, -1]
        out[k + 1] = y[0]
    x = pb.simulate(pb.Model(), None, p, dt_s=dt)[0]
    print(f"Radau took {time.time() - start:.0f} s")
    print(f"max_abs_error_m: {np.abs(x - out).max():.3e}")


if __name__ == "__main__":
    main()
