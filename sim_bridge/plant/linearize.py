"""Numerical Jacobian of the plant in reduced (minimal) coordinates, for checking the analytic linearization.

The plant (:mod:`sim_bridge.plant.dynamics`) carries the cable as a unit vector ``r`` and its rate (6 numbers for
4 degrees of freedom), so its 18x18 Jacobian is not the paper's linear model. Here the cable is described by
the planar swing angles of errata C5 (``alpha_y = atan2(r1, -r3)``, ``alpha_x = atan2(r2, -r3)``), which are
regular at the rest position, and the derivative is differentiated by central differences.

Reduced state (16 floats, SI, world NWU; the same order as ``offboard/control/linear_model.py``)::

    x, y, z, x', y', z', phi, theta, psi, phi', theta', psi', alpha_y, alpha_x, alpha_y', alpha_x'

Reduced input (4 floats): thrust u (N), tau_phi, tau_theta, tau_psi (N m, body axes). Not a hot path: numpy.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from estimators.model.cable import cable_from_planar, planar_swing
from sim_bridge.plant.dynamics import PlantParams, derivative, make_input, make_state


def reduced_to_full(z: Sequence[float]) -> list[float]:
    """Reduced state (16) -> plant state (18); valid for |alpha_x|, |alpha_y| < pi/2 (load below the vehicle)."""
    r, rd = cable_from_planar(z[12], z[13], z[14], z[15])
    return make_state(z[0:3], z[3:6], z[6:9], z[9:12], r, rd)


def full_to_reduced(x: Sequence[float]) -> list[float]:
    """Plant state (18) -> reduced state (16)."""
    ay, ax, ayd, axd = planar_swing(x[12], x[13], x[14], x[15], x[16], x[17])
    return [*map(float, x[:12]), ay, ax, ayd, axd]


def reduced_derivative(z: Sequence[float], v: Sequence[float], p: PlantParams) -> list[float]:
    """Time derivative of the reduced state under the full nonlinear plant, input ``v`` = (u, tau) (4 floats).

    The planar-angle accelerations are exact: with ``N = r1 r3' - r3 r1'`` and ``Q = r1^2 + r3^2``,
    ``alpha_y' = N / Q`` and ``alpha_y'' = (N' Q - N Q') / Q^2``, ``N' = r1 r3'' - r3 r1''``,
    ``Q' = 2 (r1 r1' + r3 r3')`` (the same with r2 for alpha_x).
    """
    x = reduced_to_full(z)
    xd = derivative(0.0, x, make_input(v[0], v[1:4]), p)
    r1, r2, r3, d1, d2, d3 = x[12:18]
    a1, a2, a3 = xd[15:18]
    out = [*xd[:12]]
    _, _, ayd, axd = planar_swing(r1, r2, r3, d1, d2, d3)

    def accel(ri: float, di: float, ai: float) -> float:
        q = ri * ri + r3 * r3
        n = ri * d3 - r3 * di
        dn = ri * a3 - r3 * ai
        dq = 2.0 * (ri * di + r3 * d3)
        return (dn * q - n * dq) / (q * q)

    out += [ayd, axd, accel(r1, d1, a1), accel(r2, d2, a2)]
    return out


def hover_point(p: PlantParams, psi: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Hover operating point at heading ``psi`` (rad): all zero but psi; thrust (M + m) g."""
    z0 = np.zeros(16)
    z0[8] = psi
    v0 = np.array([(p.M + p.m) * p.g, 0.0, 0.0, 0.0])
    return z0, v0


def jacobian(
    p: PlantParams, z0: Sequence[float], v0: Sequence[float], step: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) = (d zdot / d z, d zdot / d v) at (z0, v0) by central differences (error ~ step^2, ~1e-9).

    The input step is scaled by the thrust so that both columns see a comparable relative perturbation.
    """
    z0 = np.asarray(z0, dtype=float)
    v0 = np.asarray(v0, dtype=float)
    A = np.empty((16, 16))
    B = np.empty((16, 4))
    for j in range(16):
        dz = np.zeros(16)
        dz[j] = step
        A[:, j] = (np.array(reduced_derivative(z0 + dz, v0, p)) - np.array(reduced_derivative(z0 - dz, v0, p))) / (
            2.0 * step
        )
    for j in range(4):
        dv = np.zeros(4)
        hv = step * max(1.0, abs(v0[j]))
        dv[j] = hv
        B[:, j] = (np.array(reduced_derivative(z0, v0 + dv, p)) - np.array(reduced_derivative(z0, v0 - dv, p))) / (
            2.0 * hv
        )
    return A, B
