"""The linearised model: the output's response to an extra force along the MAP trajectory.

The model linearised by :func:`pmabayes.model.linearise.linearise` (mass, damping and
stiffness with the force effects' derivatives, the Bouc-Wen force's ``dz' = kz dv + bz
dz``, the stateful effects' states), integrated by the trapezoidal rule in a small
compiled linear time-varying simulation.
"""

from __future__ import annotations

import numba
import numpy as np

from pmabayes.model.linearise import Linearisation, linearise
from pmabayes.model.model import Model
from pmabayes.model.simulator import Simulation

__all__ = ["force_response"]


@numba.njit(cache=True)
def _ltv_kernel(a_mat, b_vec, rest, forces, dt, substeps, out):  # pragma: no cover
    """Position response of ``dy' = A dy + b f`` to forces ``(k, n)`` (trapezoidal rule)."""
    n, rows = a_mat.shape[0], a_mat.shape[1]
    h = dt / substeps
    m0 = np.empty((n, rows, rows))
    m1i = np.empty((n, rows, rows))
    for k in range(n - 1):
        a = 0.5 * (a_mat[k] + a_mat[k + 1])
        m0[k] = np.eye(rows) + 0.5 * h * a
        m1i[k] = np.linalg.inv(np.eye(rows) - 0.5 * h * a)
    y = np.zeros(rows)
    rhs = np.zeros(rows)
    for j in range(forces.shape[0]):
        for r in range(rows):
            y[r] = rest[r] * forces[j, 0]  # the static rest shifts under a force at rest
        out[j, 0] = y[0]
        for k in range(n - 1):
            df = forces[j, k + 1] - forces[j, k]
            for s in range(substeps):
                f0 = forces[j, k] + df * s / substeps
                f1 = forces[j, k] + df * (s + 1) / substeps
                for r in range(rows):
                    acc = 0.0
                    for c in range(rows):
                        acc += m0[k, r, c] * y[c]
                    rhs[r] = acc + 0.5 * h * (f0 + f1) * b_vec[r]
                for r in range(rows):
                    acc = 0.0
                    for c in range(rows):
                        acc += m1i[k, r, c] * rhs[c]
                    y[r] = acc
            out[j, k + 1] = y[0]


def linearised_plant(model: Model, values: dict, sim: Simulation, dt_s: float) -> Linearisation:
    """The model linearised along its MAP trajectory (its force effects, their states and
    the Bouc-Wen law, by :func:`pmabayes.model.linearise.linearise`), for
    :func:`force_response`."""
    theta = model.theta({k: v for k, v in values.items() if k in model.parameter_names})[0]
    return linearise(model, theta, sim.true_position_m[0], sim.velocity_m_s[0],
                     sim.pressure_pa[0], sim.hysteresis_n[0], dt_s)


def force_response(plant: Linearisation, forces_n: np.ndarray, *, substeps: int = 4) -> np.ndarray:
    """Position response of the linearised model to extra forces along its trajectory.

    Parameters
    ----------
    plant : Linearisation
        The model linearised along its trajectory (from the diagnosis' MAP,
        :func:`linearised_plant`).
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
    _ltv_kernel(np.ascontiguousarray(plant.a), np.ascontiguousarray(plant.b),
                np.ascontiguousarray(plant.rest), f, plant.dt_s, int(substeps), out)
    return out
