"""The linearised model: the output's response to an extra force along the MAP trajectory.

Mass, damping and stiffness with the force effects' derivatives, and the Bouc-Wen
force's own linearisation ``dz' = kz dv + bz dz``, integrated by the trapezoidal rule
in a small compiled linear time-varying simulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from pmabayes.model.model import Model
from pmabayes.model.simulator import Simulation

__all__ = ["force_response"]


@numba.njit(cache=True)
def _ltv_kernel(mass, damp, stiff, kz, bz, forces, dt, substeps, out):  # pragma: no cover
    """Position response of the linearised plant to forces ``(k, n)`` (trapezoidal rule)."""
    n = damp.size
    h = dt / substeps
    m0 = np.empty((n, 3, 3))
    m1i = np.empty((n, 3, 3))
    a = np.zeros((3, 3))
    for k in range(n - 1):
        c = 0.5 * (damp[k] + damp[k + 1])
        kk = 0.5 * (stiff[k] + stiff[k + 1])
        az = 0.5 * (kz[k] + kz[k + 1])
        bb = 0.5 * (bz[k] + bz[k + 1])
        a[0, 1] = 1.0
        a[1, 0] = -kk / mass
        a[1, 1] = -c / mass
        a[1, 2] = -1.0 / mass
        a[2, 1] = az
        a[2, 2] = bb
        m1 = np.eye(3) - 0.5 * h * a
        m0[k] = np.eye(3) + 0.5 * h * a
        m1i[k] = np.linalg.inv(m1)
    y = np.zeros(3)
    rhs = np.zeros(3)
    for j in range(forces.shape[0]):
        y[0] = -forces[j, 0] / stiff[0]  # the static rest shifts under a force at rest
        y[1] = 0.0
        y[2] = 0.0
        out[j, 0] = y[0]
        for k in range(n - 1):
            df = forces[j, k + 1] - forces[j, k]
            for s in range(substeps):
                f0 = forces[j, k] + df * s / substeps
                f1 = forces[j, k] + df * (s + 1) / substeps
                for r in range(3):
                    rhs[r] = m0[k, r, 0] * y[0] + m0[k, r, 1] * y[1] + m0[k, r, 2] * y[2]
                rhs[1] -= 0.5 * h * (f0 + f1) / mass
                for r in range(3):
                    y[r] = m1i[k, r, 0] * rhs[0] + m1i[k, r, 1] * rhs[1] + m1i[k, r, 2] * rhs[2]
            out[j, k + 1] = y[0]


@dataclass(frozen=True)
class Plant:
    """The model's coefficients along its MAP trajectory, for the linear response."""

    mass: float
    damp: np.ndarray
    stiff: np.ndarray
    kz: np.ndarray
    bz: np.ndarray
    dt: float


def linearised_plant(model: Model, values: dict, sim: Simulation, dt_s: float) -> Plant:
    """The model's coefficients along its MAP trajectory (force effects' derivatives and
    the Bouc-Wen force's linearisation), for :func:`force_response`."""
    theta = model.theta({k: v for k, v in values.items() if k in model.parameter_names})[0]
    x, v = sim.true_position_m[0], sim.velocity_m_s[0]
    p, z = sim.pressure_pa[0], sim.hysteresis_n[0]
    fx, fv = np.zeros_like(x), np.zeros_like(x)
    for eff, sl in model.effect_slices():
        if eff.stage != "force":
            continue
        q = np.ascontiguousarray(theta[sl])
        for k in range(x.size):
            r = eff.physics(q, x[k], v[k], p[k])
            fx[k] += r[1]
            fv[k] += r[2]
    alpha, beta, gamma = (float(values[n]) for n in ("alpha", "beta", "gamma"))
    c = beta * np.where(v * z >= 0.0, 1.0, -1.0) + gamma
    kz = alpha - c * np.abs(z)
    bz = -v * c * np.where(z >= 0.0, 1.0, -1.0)
    return Plant(model.rig.moving_mass_kg, float(values["d"]) + fv,
                  float(values["K_e"]) + fx, kz, bz, dt_s)


def force_response(plant: Plant, forces_n: np.ndarray, *, substeps: int = 4) -> np.ndarray:
    """Position response of the linearised model to extra forces along its trajectory.

    Parameters
    ----------
    plant : Plant
        The model's coefficients along its trajectory (from the diagnosis' MAP).
    forces_n : numpy.ndarray
        ``(k, n_samples)`` forces on the left of the equation of motion (opposing
        extension, as a force effect's), one per row.
    substeps : int
        Trapezoidal steps per sample interval.

    Returns
    -------
    numpy.ndarray
        ``(k, n_samples)`` change of the position, to first order in the forces.
    """
    f = np.ascontiguousarray(np.atleast_2d(forces_n), dtype=float)
    out = np.empty_like(f)
    _ltv_kernel(plant.mass, np.ascontiguousarray(plant.damp), np.ascontiguousarray(plant.stiff),
                np.ascontiguousarray(plant.kz), np.ascontiguousarray(plant.bz), f, plant.dt,
                int(substeps), out)
    return out
