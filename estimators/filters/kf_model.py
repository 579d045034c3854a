"""The torque-driven Kalman filter's model (``estimators.filters.kf``): the layout of its state, its noise
assumptions and its continuous-time blocks (the derivation is in ``kf``'s docstring and ``docs/estimation.md``).

Shared by the filter's public class (``kf``), its prediction / discretization (``kf_predict``) and its gated
updates (``kf_update``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.filters.fusion import MeasurementNoise
from estimators.filters.linear_block import LinearBlock
from estimators.model.flatness import FlatConstants
from estimators.model.vehicle import Vehicle

#: command input columns of each block (horizontal x and y, heading, height) and its slice of the output
N_INPUTS = 6  # x axis: n'' and the nonlinear remainder of a''; the same for y; psi''; z''

STATE_NAMES: tuple[str, ...] = (
    "p_x",
    "v_x",
    "alpha_y",
    "alpha_y_rate",
    "n_x",
    "n_x_rate",
    "d_x",
    "b_x",
    "p_y",
    "v_y",
    "alpha_x",
    "alpha_x_rate",
    "n_y",
    "n_y_rate",
    "d_y",
    "b_y",
    "psi",
    "psi_rate",
    "z",
    "z_rate",
    "d_z",
    "b_z",
)
#: indices in one horizontal axis
IP, IV, IA, IAD, IN, IND, ID, IB = range(8)
#: dimension of the NEES (p, v, a, a', n, n' per axis; psi, psi'; z, z')
NEES_DOF = 16


@dataclass(frozen=True)
class Tuning(MeasurementNoise):
    """Noise assumptions of the filter (SI, rad). Measurement standard deviations are those of the
    ``px4-typical`` sensor preset; process noises are continuous spectral densities (units^2 / Hz of the
    driven state's derivative); prior standard deviations are used by :meth:`KalmanEstimator.initialize`.
    """

    q_v: float = 2e-3  # (m/s^2)^2/Hz, white acceleration on v'
    q_a: float = 0.05  # (rad/s^2)^2/Hz, white angular acceleration of the swing
    q_n: float = 0.05  # (rad/s^2)^2/Hz, tilt acceleration not explained by the torque command
    q_d: float = 0.5  # (m/s^3)^2/Hz, random walk of the unknown acceleration d
    q_b: float = 1e-7  # (m/s^3)^2/Hz, random walk of the accelerometer bias
    q_psi: float = 0.005  # (rad/s^2)^2/Hz
    q_vz: float = 3e-4  # (m/s^2)^2/Hz
    q_dz: float = 0.05  # (m/s^3)^2/Hz
    prior_pos: float = 0.05
    prior_vel: float = 0.1
    prior_swing: float = 0.15
    prior_swing_rate: float = 0.5
    prior_tilt: float = 0.02
    prior_tilt_rate: float = 0.05
    prior_d: float = 0.3
    prior_bias: float = 0.1
    prior_psi: float = 0.02
    prior_psi_rate: float = 0.05
    prior_z: float = 0.05
    prior_z_rate: float = 0.1
    prior_dz: float = 0.3
    gate_probability: float = 0.9999
    gate_reopen: int = 10
    accel_gain_filter: float = 0.1  # weight of a new sample in the low-pass of the vertical specific force


def model_blocks(vehicle: Vehicle, k: FlatConstants, tn: Tuning) -> tuple[LinearBlock, LinearBlock, LinearBlock]:
    """The three continuous-time blocks (horizontal, both axes side by side; heading; height) of the filter on
    ``vehicle`` (flat constants ``k``) with the process noises of ``tn``: ``x' = A x + B w`` and the diagonal
    spectral densities of the noise on each state (the model of ``kf``'s docstring)."""
    M, m, l, g = vehicle.mass_vehicle, vehicle.mass_load, vehicle.cable_length, vehicle.gravity
    Mt = M + m
    a = np.zeros((8, 8))
    a[IP, IV] = 1.0
    a[IV, IN] = Mt * g / M
    a[IV, IA] = m * g / M
    a[IV, ID] = 1.0
    a[IA, IAD] = 1.0
    a[IAD, IA] = -k.omega2
    a[IAD, IN] = -k.omega2
    a[IAD, ID] = -1.0 / l
    a[IN, IND] = 1.0
    b = np.zeros((8, 2))
    b[IND, 0] = 1.0  # world tilt acceleration from the torque command
    b[IAD, 1] = 1.0  # nonlinear remainder of a'' at the estimate
    hb = LinearBlock(a, b, (0.0, tn.q_v, 0.0, tn.q_a, 0.0, tn.q_n, tn.q_d, tn.q_b), batch=2)
    yb = LinearBlock(np.array([[0.0, 1.0], [0.0, 0.0]]), (0.0, 1.0), (0.0, tn.q_psi), batch=1)
    az = np.zeros((4, 4))
    az[0, 1] = az[1, 2] = 1.0
    zb = LinearBlock(az, (0.0, 1.0, 0.0, 0.0), (0.0, tn.q_vz, tn.q_dz, tn.q_b), batch=1)
    return hb, yb, zb


__all__ = [
    "IA",
    "IAD",
    "IB",
    "ID",
    "IN",
    "IND",
    "IP",
    "IV",
    "NEES_DOF",
    "N_INPUTS",
    "STATE_NAMES",
    "Tuning",
    "model_blocks",
]
