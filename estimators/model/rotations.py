"""Rotation primitives shared by the controller, the filters and the emulator (``estimators`` is the one layer both
sides may import): quaternion algebra, the thrust direction, and body rates <-> Euler-angle rates.

Model frame (``estimators.model.frames``): world NWU, body FLU, ZYX Euler angles (phi, theta, psi), body to world
``R = Rz(psi) Ry(theta) Rx(phi)``; quaternions ``(w, x, y, z)``, Hamilton product; rad, rad/s. Plain floats: these
run inside the control tick and the emulator's 1 kHz inner loops.
"""

from __future__ import annotations

import math

Quat = tuple[float, float, float, float]


def quat_mul(a: Quat, b: Quat) -> Quat:
    """Hamilton product ``a * b`` (the rotation b, then a)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conj(q: Quat) -> Quat:
    """The conjugate (the inverse rotation of a unit quaternion)."""
    return (q[0], -q[1], -q[2], -q[3])


def quat_normalize(q: Quat) -> Quat:
    """``q / |q|`` (``q`` non-zero)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def thrust_direction(phi: float, theta: float, psi: float) -> tuple[float, float, float]:
    """``n = R e3``: the body z axis (the thrust's direction) in the world frame (errata C2)."""
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    return thrust_direction_trig(sf, cf, st, ct, sp, cp)


def thrust_direction_trig(
    sf: float, cf: float, st: float, ct: float, sp: float, cp: float
) -> tuple[float, float, float]:
    """:func:`thrust_direction` from the sines and cosines of (phi, theta, psi), for callers that need them too
    (the plant's derivative, the laws' steps)."""
    return (sf * sp + cf * cp * st, cf * sp * st - cp * sf, cf * ct)


def body_rates(
    phi: float, theta: float, phi_rate: float, theta_rate: float, psi_rate: float
) -> tuple[float, float, float]:
    """Body angular velocity (p, q, r), rad/s FLU, from the Euler angles and their rates: ``omega = W(eta) eta'``
    (errata E4)."""
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    return (phi_rate - st * psi_rate, cf * theta_rate + sf * ct * psi_rate, -sf * theta_rate + cf * ct * psi_rate)


def euler_rates(phi: float, theta: float, p: float, q: float, r: float) -> tuple[float, float, float]:
    """Euler-angle rates (phi', theta', psi'), rad/s, from the body rates (p, q, r) (rad/s, FLU): ``eta' = W^-1
    omega``. Singular at ``cos(theta) = 0``: the caller refuses attitudes near it."""
    sf, cf = math.sin(phi), math.cos(phi)
    ct = math.cos(theta)
    tt = math.tan(theta)
    return (p + sf * tt * q + cf * tt * r, cf * q - sf * r, (sf * q + cf * r) / ct)


__all__ = [
    "Quat",
    "body_rates",
    "euler_rates",
    "quat_conj",
    "quat_mul",
    "quat_normalize",
    "thrust_direction",
    "thrust_direction_trig",
]
