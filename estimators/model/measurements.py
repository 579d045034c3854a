"""Typed measurement records: what the autopilot (or an extra sensor) reported, and when it was sampled.

One record per MAVLink message kind the estimators consume. Everything is already in slung's model frame
(world NWU z up, body FLU, ZYX Euler angles; ``estimators.model.frames`` does the NED/FRD conversion at the link),
SI units and radians. Producers: the sensor models (``sim_bridge.plant.sensors``), the live MAVLink link and the
tlog replay reader. Consumer: the Kalman filters (``estimators.filters.kf``).

Every record carries ``t``: the vehicle time (s) at which the quantity was SAMPLED, not the time it was
delivered; the filters use it to place the measurement on their time axis.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class PositionVelocity(NamedTuple):
    """The autopilot's own position and velocity estimate (LOCAL_POSITION_NED / ODOMETRY), world NWU.

    x, y, z: m (z up); vx, vy, vz: m/s.
    """

    t: float
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float


class Attitude(NamedTuple):
    """Attitude (ATTITUDE): ZYX Euler angles phi, theta, psi (rad, model frame) and BODY rates p, q, r
    (rad/s, body FLU). Body rates are not Euler-angle rates (errata E4: ``omega = W(eta) eta'``)."""

    t: float
    phi: float
    theta: float
    psi: float
    p: float
    q: float
    r: float


class Imu(NamedTuple):
    """Inertial sample (HIGHRES_IMU / SCALED_IMU), body FLU: accelerometer specific force ax, ay, az
    (m/s^2; at rest, level: az = +g) and gyro gx, gy, gz (rad/s)."""

    t: float
    ax: float
    ay: float
    az: float
    gx: float
    gy: float
    gz: float


class LoadAngle(NamedTuple):
    """Cable-angle sensor: planar swing angles alpha_x, alpha_y (rad, errata C5, world frame: alpha_y > 0
    with the load at +x, alpha_x > 0 with the load at +y)."""

    t: float
    alpha_x: float
    alpha_y: float


class ReportedAccuracy(NamedTuple):
    """The autopilot's own accuracy of its position estimate, 1 sigma (ESTIMATOR_STATUS pos_horiz_accuracy /
    pos_vert_accuracy, else GPS_RAW_INT h_acc / v_acc): pos_h horizontal, pos_v vertical, m. Not a measurement of
    the state: the filter that uses it bounds its position noise with it (``estimators.filters.measured_kf``)."""

    t: float
    pos_h: float
    pos_v: float


Measurement = PositionVelocity | Attitude | Imu | LoadAngle | ReportedAccuracy

#: The record types, in the order the filters dispatch them.
MEASUREMENT_TYPES: tuple[type, ...] = (PositionVelocity, Attitude, Imu, LoadAngle, ReportedAccuracy)


def is_finite(m: Measurement) -> bool:
    """True when every field of the record (time included) is a finite number."""
    isf = math.isfinite
    return all(isf(v) for v in m)


__all__ = [
    "MEASUREMENT_TYPES",
    "Attitude",
    "Imu",
    "LoadAngle",
    "Measurement",
    "PositionVelocity",
    "ReportedAccuracy",
    "is_finite",
]
