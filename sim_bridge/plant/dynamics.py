"""Plant: full nonlinear quadrotor + spherical pendulum, integrated on the unit sphere.

The derivative is a pure function ``derivative(t, x, u, params)`` (python-control's convention) of plain
floats, so the same function serves integration, linearization and tests, and costs a few microseconds.

Model (``docs/model.md``; paper Section 2 with the errata's conventions C1-C4 and the sphere form E16):

- world frame NWU (z up), body frame FLU, ZYX Euler angles ``R = Rz(psi) Ry(theta) Rx(phi)``;
- thrust ``u`` (N) along the body z axis, ``n = R e3``; torques ``tau`` (N m) about the body axes;
- point-mass load ``m`` on a massless rigid cable of length ``l`` attached at the vehicle's centre of mass,
  cable direction ``r`` (unit vector, vehicle to load) and its rate ``r'``;
- rotation: either the paper's simplification (13) ``eta'' = tau / I`` (``attitude_model="paper"``, the
  default, which reproduces the paper) or the full rigid body with Euler's equations
  ``I w' = tau - w x I w`` and ``w = W(eta) eta'`` (``attitude_model="rigid"``, used by the emulator).

State vector ``x`` (18 floats, SI):

====== ================================== =========
index  quantity                           unit
====== ================================== =========
0-2    vehicle position (x, y, z) NWU     m
3-5    vehicle velocity                   m/s
6-8    Euler angles (phi, theta, psi)     rad
9-11   Euler angle rates                  rad/s
12-14  cable direction r (unit)           1
15-17  cable direction rate r'            1/s
====== ================================== =========

Input vector ``u`` (13 floats): thrust (N), torques tau_phi, tau_theta, tau_psi (N m, body axes), external
force on the vehicle (N, world), external force on the load (N, world), external torque (N m, body axes). The
plants that integrate this model put a vehicle's still-air drag into the external slots (:func:`apply_drag`).

Cable tension (errata E5, with external forces)::

    T = (m M l |r'|^2 + M (r . F_L) - m r . (u n + F_Q)) / (M + m)

The rigid cable model holds only while ``T > 0``; :func:`tension` lets callers detect a slack cable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from estimators.model.rotations import body_rates, thrust_direction, thrust_direction_trig
from estimators.model.vehicle import Vehicle

STATE_SIZE = 18
INPUT_SIZE = 13

# State indices, named so call sites say what they read.
POS = slice(0, 3)
VEL = slice(3, 6)
EULER = slice(6, 9)
EULER_RATE = slice(9, 12)
CABLE = slice(12, 15)
CABLE_RATE = slice(15, 18)


class PlantParams(NamedTuple):
    """Constants the derivative needs, unpacked from a :class:`Vehicle` once (SI units)."""

    M: float
    m: float
    l: float
    g: float
    I_phi: float
    I_theta: float
    I_psi: float
    rigid_body: bool


def plant_params(vehicle: Vehicle, attitude_model: str = "paper") -> PlantParams:
    """Plant constants from a vehicle description; ``attitude_model`` is ``"paper"`` or ``"rigid"``."""
    if attitude_model not in ("paper", "rigid"):
        raise ValueError(f"attitude_model must be 'paper' or 'rigid', got {attitude_model!r}")
    i_phi, i_theta, i_psi = vehicle.inertia
    return PlantParams(
        vehicle.mass_vehicle,
        vehicle.mass_load,
        vehicle.cable_length,
        vehicle.gravity,
        i_phi,
        i_theta,
        i_psi,
        attitude_model == "rigid",
    )


def make_input(
    thrust: float,
    torque: Sequence[float] = (0.0, 0.0, 0.0),
    force_vehicle: Sequence[float] = (0.0, 0.0, 0.0),
    force_load: Sequence[float] = (0.0, 0.0, 0.0),
    torque_external: Sequence[float] = (0.0, 0.0, 0.0),
) -> list[float]:
    """Pack the plant input vector (see module docstring for units and frames)."""
    return [
        float(thrust),
        *map(float, torque),
        *map(float, force_vehicle),
        *map(float, force_load),
        *map(float, torque_external),
    ]


def make_state(
    position: Sequence[float] = (0.0, 0.0, 0.0),
    velocity: Sequence[float] = (0.0, 0.0, 0.0),
    euler: Sequence[float] = (0.0, 0.0, 0.0),
    euler_rate: Sequence[float] = (0.0, 0.0, 0.0),
    cable: Sequence[float] = (0.0, 0.0, -1.0),
    cable_rate: Sequence[float] = (0.0, 0.0, 0.0),
) -> list[float]:
    """Pack a state vector; the cable direction is normalized and its rate made tangent to the sphere."""
    r = [float(c) for c in cable]
    nr = math.sqrt(r[0] ** 2 + r[1] ** 2 + r[2] ** 2)
    if not nr > 0.0:
        raise ValueError("cable direction must be a non-zero vector")
    r = [c / nr for c in r]
    rd = [float(c) for c in cable_rate]
    dot = r[0] * rd[0] + r[1] * rd[1] + r[2] * rd[2]
    rd = [rd[i] - dot * r[i] for i in range(3)]
    return [*map(float, position), *map(float, velocity), *map(float, euler), *map(float, euler_rate), *r, *rd]


def tension(x: Sequence[float], u: Sequence[float], p: PlantParams) -> float:
    """Cable tension, N (positive pulls the vehicle toward the load). ``<= 0`` means a slack cable."""
    n1, n2, n3 = thrust_direction(x[6], x[7], x[8])
    r1, r2, r3 = x[12], x[13], x[14]
    d1, d2, d3 = x[15], x[16], x[17]
    thrust = u[0]
    rq = r1 * (thrust * n1 + u[4]) + r2 * (thrust * n2 + u[5]) + r3 * (thrust * n3 + u[6])
    rl = r1 * u[7] + r2 * u[8] + r3 * u[9]
    return (p.m * p.M * p.l * (d1 * d1 + d2 * d2 + d3 * d3) + p.M * rl - p.m * rq) / (p.M + p.m)


def derivative(t: float, x: Sequence[float], u: Sequence[float], p: PlantParams) -> list[float]:
    """Time derivative of the state (see module docstring). Pure: no I/O, no hidden state; ``t`` unused."""
    phi, theta, psi = x[6], x[7], x[8]
    dphi, dtheta, dpsi = x[9], x[10], x[11]
    r1, r2, r3 = x[12], x[13], x[14]
    d1, d2, d3 = x[15], x[16], x[17]
    M, m, l, g = p.M, p.m, p.l, p.g
    thrust = u[0]

    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    n1, n2, n3 = thrust_direction_trig(sf, cf, st, ct, sp, cp)

    # Force on the vehicle other than the cable: thrust + external.
    q1 = thrust * n1 + u[4]
    q2 = thrust * n2 + u[5]
    q3 = thrust * n3 + u[6]
    rd2 = d1 * d1 + d2 * d2 + d3 * d3
    rq = r1 * q1 + r2 * q2 + r3 * q3
    rl = r1 * u[7] + r2 * u[8] + r3 * u[9]
    T = (m * M * l * rd2 + M * rl - m * rq) / (M + m)

    ax = (q1 + T * r1) / M
    ay = (q2 + T * r2) / M
    az = (q3 + T * r3) / M - g

    # Relative acceleration of load and vehicle without the cable, projected on the sphere's tangent plane;
    # the radial part is fixed by the constraint r . r'' = -|r'|^2.
    if m > 0.0:
        w1 = u[7] / m - q1 / M
        w2 = u[8] / m - q2 / M
        w3 = u[9] / m - q3 / M
    else:
        w1, w2, w3 = -q1 / M, -q2 / M, -q3 / M
    wr = w1 * r1 + w2 * r2 + w3 * r3
    inv_l = 1.0 / l
    dd1 = (w1 - wr * r1) * inv_l - rd2 * r1
    dd2 = (w2 - wr * r2) * inv_l - rd2 * r2
    dd3 = (w3 - wr * r3) * inv_l - rd2 * r3

    tp = u[1] + u[10]
    tt = u[2] + u[11]
    ts = u[3] + u[12]
    if not p.rigid_body:
        ddphi, ddtheta, ddpsi = tp / p.I_phi, tt / p.I_theta, ts / p.I_psi
    else:
        ddphi, ddtheta, ddpsi = _rigid_body_euler_accel(sf, cf, st, ct, dphi, dtheta, dpsi, tp, tt, ts, p)

    return [x[3], x[4], x[5], ax, ay, az, dphi, dtheta, dpsi, ddphi, ddtheta, ddpsi, d1, d2, d3, dd1, dd2, dd3]


def _rigid_body_euler_accel(
    sf: float,
    cf: float,
    st: float,
    ct: float,
    dphi: float,
    dtheta: float,
    dpsi: float,
    tp: float,
    tt: float,
    ts: float,
    p: PlantParams,
) -> tuple[float, float, float]:
    """Euler-angle accelerations of a rigid body: ``eta'' = W^-1 (w' - W' eta')`` with Euler's equations.

    ``w = W eta'`` with ``W = [[1, 0, -S_t], [0, C_f, S_f C_t], [0, -S_f, C_f C_t]]`` (errata E4).
    """
    wx = dphi - st * dpsi
    wy = cf * dtheta + sf * ct * dpsi
    wz = -sf * dtheta + cf * ct * dpsi
    Ix, Iy, Iz = p.I_phi, p.I_theta, p.I_psi
    ax = (tp - (Iz - Iy) * wy * wz) / Ix
    ay = (tt - (Ix - Iz) * wz * wx) / Iy
    az = (ts - (Iy - Ix) * wx * wy) / Iz
    # W' eta'
    c1 = -ct * dtheta * dpsi
    c2 = -sf * dphi * dtheta + (cf * ct * dphi - sf * st * dtheta) * dpsi
    c3 = -cf * dphi * dtheta + (-sf * ct * dphi - cf * st * dtheta) * dpsi
    b1, b2, b3 = ax - c1, ay - c2, az - c3
    # W^-1 = [[1, S_f T_t, C_f T_t], [0, C_f, -S_f], [0, S_f / C_t, C_f / C_t]]
    tt_ = st / ct
    return (b1 + sf * tt_ * b2 + cf * tt_ * b3, cf * b2 - sf * b3, (sf * b2 + cf * b3) / ct)


def apply_drag(
    u: list[float], x: Sequence[float], force: Sequence[float], torque: Sequence[float], linear: float, angular: float
) -> None:
    """In place: ``u``'s external force on the vehicle (slots 4-6) becomes ``force`` and its external torque (slots
    10-12) ``torque`` (the disturbance's alone, N world and N m body) plus still-air drag at the state ``x``: a
    force ``-linear * v`` on the vehicle (N per m/s, world frame; PX4 SIH's SIH_KDV) and a torque ``-angular * w``
    (N m per rad/s, body rates from the Euler angles and their rates; SIH_KDW). The caller holds ``u`` over one
    plant step, so the drag is that of the step's start. A zero coefficient leaves its slots alone."""
    if linear > 0.0:
        u[4], u[5], u[6] = force[0] - linear * x[3], force[1] - linear * x[4], force[2] - linear * x[5]
    if angular > 0.0:
        wx, wy, wz = body_rates(x[6], x[7], x[9], x[10], x[11])
        u[10], u[11], u[12] = torque[0] - angular * wx, torque[1] - angular * wy, torque[2] - angular * wz


def rk4_step(x: Sequence[float], u: Sequence[float], p: PlantParams, h: float, t: float = 0.0) -> list[float]:
    """One classical RK4 step of length ``h`` (s) with the input held (zero-order hold).

    After the step the cable state is projected back onto the constraint manifold
    (``|r| = 1``, ``r . r' = 0``), which the exact flow preserves and RK4 keeps only to O(h^5).
    """
    k1 = derivative(t, x, u, p)
    hh = 0.5 * h
    x2 = [a + hh * b for a, b in zip(x, k1)]
    k2 = derivative(t + hh, x2, u, p)
    x3 = [a + hh * b for a, b in zip(x, k2)]
    k3 = derivative(t + hh, x3, u, p)
    x4 = [a + h * b for a, b in zip(x, k3)]
    k4 = derivative(t + h, x4, u, p)
    h6 = h / 6.0
    y = [a + h6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
    project_cable(y)
    return y


def project_cable(x: list[float]) -> None:
    """In place: normalize ``r`` and remove the radial component of ``r'``."""
    r1, r2, r3 = x[12], x[13], x[14]
    inv = 1.0 / math.sqrt(r1 * r1 + r2 * r2 + r3 * r3)
    r1, r2, r3 = r1 * inv, r2 * inv, r3 * inv
    x[12], x[13], x[14] = r1, r2, r3
    dot = r1 * x[15] + r2 * x[16] + r3 * x[17]
    x[15] -= dot * r1
    x[16] -= dot * r2
    x[17] -= dot * r3


def energy(x: Sequence[float], p: PlantParams) -> float:
    """Total mechanical energy, J (errata E5). Rotational energy uses the model's rotation law.

    For ``attitude_model="paper"`` the rotational energy is ``1/2 sum I_i eta_i'^2`` (consistent with (13));
    for the rigid body it is ``1/2 w^T I w``.
    """
    M, m, l, g = p.M, p.m, p.l, p.g
    v1, v2, v3 = x[3], x[4], x[5]
    vp1, vp2, vp3 = v1 + l * x[15], v2 + l * x[16], v3 + l * x[17]
    kin = 0.5 * M * (v1 * v1 + v2 * v2 + v3 * v3) + 0.5 * m * (vp1 * vp1 + vp2 * vp2 + vp3 * vp3)
    dphi, dtheta, dpsi = x[9], x[10], x[11]
    if p.rigid_body:
        sf, cf = math.sin(x[6]), math.cos(x[6])
        st, ct = math.sin(x[7]), math.cos(x[7])
        wx = dphi - st * dpsi
        wy = cf * dtheta + sf * ct * dpsi
        wz = -sf * dtheta + cf * ct * dpsi
        rot = 0.5 * (p.I_phi * wx * wx + p.I_theta * wy * wy + p.I_psi * wz * wz)
    else:
        rot = 0.5 * (p.I_phi * dphi * dphi + p.I_theta * dtheta * dtheta + p.I_psi * dpsi * dpsi)
    pot = M * g * x[2] + m * g * (x[2] + l * x[14])
    return kin + rot + pot


def load_position(x: Sequence[float], p: PlantParams) -> tuple[float, float, float]:
    """Load position ``xi + l r``, m, world NWU."""
    return (x[0] + p.l * x[12], x[1] + p.l * x[13], x[2] + p.l * x[14])


def hover_input(p: PlantParams) -> list[float]:
    """The input that holds the vehicle in hover with the load at rest: ``u = (M + m) g``, no torque."""
    return make_input((p.M + p.m) * p.g)
