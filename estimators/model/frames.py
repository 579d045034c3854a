"""The one place where MAVLink's NED / FRD frames meet slung's model frame.

Model frame (used everywhere inside slung, see ``docs/model.md``):

- world: **NWU**, x north, y west, z up (the paper's z-up inertial frame, C1 of the errata);
- body: **FLU**, x forward, y left, z up; thrust acts along +z body;
- attitude: ZYX Euler angles (phi roll, theta pitch, psi yaw), body to world ``R = Rz(psi) Ry(theta) Rx(phi)``.

MAVLink (PX4 and ArduPilot) uses world **NED** and body **FRD**. Both changes are a rotation by pi about the
x axis, ``P = diag(1, -1, -1)``, so

- vectors: ``v_ned = P v_nwu`` and ``w_frd = P w_flu`` (the map is its own inverse);
- rotations: ``R_ned = P R_model P``, i.e. Euler angles ``(phi, -theta, -psi)``;
- quaternions ``(w, x, y, z)``: ``q_ned = (w, x, -y, -z)``;
- a positive model pitch (thrust tilted toward +x, nose down) is a negative MAVLink pitch (nose down in FRD).

Every conversion is its own inverse; the functions come in named pairs so call sites say which way they go.

Units at the wire: MAVLink's SCALED_IMU / RAW_IMU accelerations are in milli-g of standard gravity
(``STANDARD_GRAVITY``, 9.80665 m/s^2, the one spelling of it in slung), HIGHRES_IMU's in m/s^2.
"""

from __future__ import annotations

import math

#: m/s^2, standard gravity (CGPM 1901): the "g" of MAVLink's milli-g accelerations and of specific forces in g
STANDARD_GRAVITY = 9.80665


def ned_to_model_vector(x: float, y: float, z: float) -> tuple[float, float, float]:
    """World vector NED -> model NWU (positions, velocities, accelerations, forces)."""
    return (x, -y, -z)


def model_to_ned_vector(x: float, y: float, z: float) -> tuple[float, float, float]:
    """World vector model NWU -> NED."""
    return (x, -y, -z)


def frd_to_model_body(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Body vector FRD -> model FLU (body rates, specific force, body torques)."""
    return (x, -y, -z)


def model_body_to_frd(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Body vector model FLU -> FRD."""
    return (x, -y, -z)


def ned_euler_to_model(roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
    """MAVLink ZYX Euler angles (rad, NED/FRD) -> model (phi, theta, psi) (rad, NWU/FLU)."""
    return (roll, -pitch, _wrap(-yaw))


def model_euler_to_ned(phi: float, theta: float, psi: float) -> tuple[float, float, float]:
    """Model (phi, theta, psi) -> MAVLink (roll, pitch, yaw), rad, yaw wrapped to (-pi, pi]."""
    return (phi, -theta, _wrap(-psi))


def ned_quaternion_to_model(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """MAVLink quaternion (w, x, y, z), FRD body to NED world -> model quaternion, FLU body to NWU world."""
    return (w, x, -y, -z)


def model_quaternion_to_ned(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """Model quaternion (FLU body to NWU world) -> MAVLink quaternion (FRD body to NED world)."""
    return (w, x, -y, -z)


def euler_to_quaternion(phi: float, theta: float, psi: float) -> tuple[float, float, float, float]:
    """ZYX Euler angles (rad) -> unit quaternion (w, x, y, z) of ``Rz(psi) Ry(theta) Rx(phi)``.

    Frame-agnostic: gives a model quaternion from model angles and a NED one from NED angles.
    """
    cr, sr = math.cos(0.5 * phi), math.sin(0.5 * phi)
    cp, sp = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cy, sy = math.cos(0.5 * psi), math.sin(0.5 * psi)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quaternion_to_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Unit quaternion (w, x, y, z) -> ZYX Euler angles (phi, theta, psi), rad; normalizes first."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError("quaternion has zero or non-finite norm")
    w, x, y, z = w / n, x / n, y / n, z / n
    phi = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    s = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    theta = math.asin(s)
    psi = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (phi, theta, psi)


def milli_g_to_m_s2(v: float) -> float:
    """An acceleration in MAVLink's milli-g (SCALED_IMU / RAW_IMU ``xacc`` ...) -> m/s^2."""
    return v * STANDARD_GRAVITY * 1e-3


def m_s2_to_milli_g(v: float) -> float:
    """An acceleration in m/s^2 -> MAVLink's milli-g (unrounded; the encoder rounds and clamps to int16)."""
    return v / STANDARD_GRAVITY * 1e3


def _wrap(angle: float) -> float:
    """Wrap an angle to (-pi, pi]; a non-finite angle gives NaN (``math.fmod`` raises on inf), which every caller's
    finiteness check then refuses."""
    if not math.isfinite(angle):
        return math.nan
    a = math.fmod(angle + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


wrap_angle = _wrap
