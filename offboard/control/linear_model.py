"""The corrected tangent linearization of the quadrotor + load at hover, as matrices (paper Section 2.1).

Operating point: hover, ``u = (M + m) g``, tilt 0, load straight below, constant heading ``psibar`` (rad).
Derived from the full nonlinear model (``docs/model.md``; errata section 2 block, E6, E7), with
``M_t = M + m`` and ``w2 = M_t g / (M l)`` (the free swing frequency squared, 1/s^2)::

    x''       = g ( M_t (theta C_psibar + phi S_psibar) + m alpha_y ) / M
    y''       = g ( M_t (theta S_psibar - phi C_psibar) + m alpha_x ) / M
    z''       = u_delta / M_t
    phi''     = tau_phi / I_phi,  theta'' = tau_theta / I_theta,  psi'' = tau_psi / I_psi
    alpha_y'' = -w2 ( alpha_y + theta C_psibar + phi S_psibar )
    alpha_x'' =  w2 ( phi C_psibar - theta S_psibar - alpha_x )

The printed (25) and (29) carry a spurious factor l on the swing term (E6) and the printed X-Z set uses the
opposite sign of alpha_y (E7); this module uses the derived equations, in the paper's own alpha_y, alpha_x
(errata C5: positive with the load at +x, +y). The same equations hold for both attitude models of the plant
(rigid body and (13)): they differ only in terms quadratic in the rates.

Full state (16, deviations from the operating point, SI, world NWU z up)::

    0 x  1 y  2 z  3 x'  4 y'  5 z'  6 phi  7 theta  8 psi  9 phi'  10 theta'  11 psi'
    12 alpha_y  13 alpha_x  14 alpha_y'  15 alpha_x'

Input (4, deviations): u_delta (N), tau_phi, tau_theta, tau_psi (N m, body axes).

Per-plane models (heading 0, the paper's (25)-(32) corrected):

- X-Z: state ``[x, x', theta, theta', alpha_y, alpha_y']``, input ``tau_theta``;
- Y-Z: state ``[y, y', phi, phi', alpha_x, alpha_x']``, input ``tau_phi``;
- vertical: ``[z, z']``, input ``u_delta``; yaw: ``[psi, psi']``, input ``tau_psi``.

For psibar != 0 the X-Z / Y-Z split holds in the heading-aligned frame; in the world frame the tilt is
``Rz(psibar) [theta, -phi]`` (see :mod:`estimators.model.flatness`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from estimators.model.control_state import INPUT_NAMES, REDUCED_STATE_NAMES
from estimators.model.vehicle import Vehicle

STATE_NAMES = REDUCED_STATE_NAMES

XZ_STATE_NAMES: tuple[str, ...] = ("x", "vx", "theta", "theta_rate", "alpha_y", "alpha_y_rate")
YZ_STATE_NAMES: tuple[str, ...] = ("y", "vy", "phi", "phi_rate", "alpha_x", "alpha_x_rate")


class LinearModel(NamedTuple):
    """``x' = A x + B u`` with named state and input components (SI)."""

    A: np.ndarray
    B: np.ndarray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]


def linear_model(vehicle: Vehicle, psibar: float = 0.0) -> LinearModel:
    """Full 16-state tangent linearization at hover with heading ``psibar`` (rad)."""
    M, m, l, g = vehicle.mass_vehicle, vehicle.mass_load, vehicle.cable_length, vehicle.gravity
    Mt = M + m
    w2 = Mt * g / (M * l)
    c, s = math.cos(psibar), math.sin(psibar)
    i_phi, i_theta, i_psi = vehicle.inertia
    A = np.zeros((16, 16))
    B = np.zeros((16, 4))
    for k in range(3):  # positions and angles integrate their rates
        A[k, 3 + k] = 1.0
        A[6 + k, 9 + k] = 1.0
    A[12, 14] = 1.0
    A[13, 15] = 1.0
    # x''
    A[3, 7] = g * Mt * c / M
    A[3, 6] = g * Mt * s / M
    A[3, 12] = g * m / M
    # y''
    A[4, 7] = g * Mt * s / M
    A[4, 6] = -g * Mt * c / M
    A[4, 13] = g * m / M
    # alpha_y''
    A[14, 12] = -w2
    A[14, 7] = -w2 * c
    A[14, 6] = -w2 * s
    # alpha_x''
    A[15, 13] = -w2
    A[15, 6] = w2 * c
    A[15, 7] = -w2 * s
    # inputs
    B[5, 0] = 1.0 / Mt
    B[9, 1] = 1.0 / i_phi
    B[10, 2] = 1.0 / i_theta
    B[11, 3] = 1.0 / i_psi
    return LinearModel(A, B, STATE_NAMES, INPUT_NAMES)


def xz_model(vehicle: Vehicle) -> LinearModel:
    """X-Z plane at heading 0: state ``[x, x', theta, theta', alpha_y, alpha_y']``, input ``tau_theta``.

    ``x'' = (M_t g theta + m g alpha_y) / M``, ``alpha_y'' = -M_t g (theta + alpha_y) / (M l)`` (E6, E7).
    """
    return _sub_model(vehicle, [0, 3, 7, 10, 12, 14], 2, XZ_STATE_NAMES, "tau_theta")


def yz_model(vehicle: Vehicle) -> LinearModel:
    """Y-Z plane at heading 0: state ``[y, y', phi, phi', alpha_x, alpha_x']``, input ``tau_phi``.

    ``y'' = (m g alpha_x - M_t g phi) / M``, ``alpha_x'' = M_t g (phi - alpha_x) / (M l)`` (E6).
    """
    return _sub_model(vehicle, [1, 4, 6, 9, 13, 15], 1, YZ_STATE_NAMES, "tau_phi")


def vertical_model(vehicle: Vehicle) -> LinearModel:
    """Height: state ``[z, z']``, input ``u_delta`` (N): ``z'' = u_delta / M_t`` ((26), (30))."""
    return _sub_model(vehicle, [2, 5], 0, ("z", "vz"), "thrust")


def yaw_model(vehicle: Vehicle) -> LinearModel:
    """Yaw: state ``[psi, psi']``, input ``tau_psi`` (N m): ``psi'' = tau_psi / I_psi``."""
    return _sub_model(vehicle, [8, 11], 3, ("psi", "psi_rate"), "tau_psi")


def _sub_model(vehicle: Vehicle, idx: list[int], inp: int, names: tuple[str, ...], inp_name: str) -> LinearModel:
    full = linear_model(vehicle, 0.0)
    A = full.A[np.ix_(idx, idx)].copy()
    B = full.B[np.ix_(idx, [inp])].copy()
    return LinearModel(A, B, names, (inp_name,))
