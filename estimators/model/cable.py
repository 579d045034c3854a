"""Cable geometry: the unit cable direction ``r`` and the paper's swing angles.

Model frame (``docs/model.md``): world NWU, z up. ``r`` is the unit vector from the vehicle to the load;
``r = (0, 0, -1)`` is the load hanging straight below (errata C3: ``r = [S_a C_b, S_a S_b, -C_a]``).

Angles, all in radians (errata C5, E16):

- ``alpha`` in [0, pi]: the swing angle from the vertical; ``beta``: azimuth of the swing plane from +x
  (undefined at alpha = 0, where this module returns beta = 0 and beta' = 0);
- ``alpha_y = atan2(r1, -r3)``: the swing projected on the X-Z plane, positive with the load at +x;
- ``alpha_x = atan2(r2, -r3)``: the swing projected on the Y-Z plane, positive with the load at +y.

Pure functions of plain floats so that the plant, the controller and the estimators can call them in their
hot paths without allocating arrays.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class SwingAngles(NamedTuple):
    """The paper's swing angles and their rates (rad, rad/s)."""

    alpha: float
    beta: float
    alpha_x: float
    alpha_y: float
    alpha_rate: float
    beta_rate: float
    alpha_x_rate: float
    alpha_y_rate: float


def swing_angles(r1: float, r2: float, r3: float, d1: float, d2: float, d3: float) -> SwingAngles:
    """Swing angles and rates from the cable direction ``r`` and its rate ``r' = (d1, d2, d3)`` (1/s)."""
    h = math.sqrt(r1 * r1 + r2 * r2)
    alpha = math.atan2(h, -r3)
    if h > 1e-12:
        beta = math.atan2(r2, r1)
        ca, sa = math.cos(alpha), math.sin(alpha)
        cb, sb = r1 / h, r2 / h
        # e_a = d r / d alpha, e_b = (d r / d beta) / S_a (errata E2)
        alpha_rate = d1 * ca * cb + d2 * ca * sb + d3 * sa
        beta_rate = (-d1 * sb + d2 * cb) / sa
    else:
        beta = 0.0
        alpha_rate = math.sqrt(d1 * d1 + d2 * d2)
        beta_rate = 0.0
    qy = r1 * r1 + r3 * r3
    qx = r2 * r2 + r3 * r3
    alpha_y = math.atan2(r1, -r3)
    alpha_x = math.atan2(r2, -r3)
    alpha_y_rate = (r1 * d3 - r3 * d1) / qy if qy > 0.0 else 0.0
    alpha_x_rate = (r2 * d3 - r3 * d2) / qx if qx > 0.0 else 0.0
    return SwingAngles(alpha, beta, alpha_x, alpha_y, alpha_rate, beta_rate, alpha_x_rate, alpha_y_rate)


def planar_swing(r1: float, r2: float, r3: float, d1: float, d2: float, d3: float) -> tuple[float, float, float, float]:
    """(alpha_y, alpha_x, alpha_y', alpha_x'): the two planar swing angles and rates only (hot path)."""
    qy = r1 * r1 + r3 * r3
    qx = r2 * r2 + r3 * r3
    return (
        math.atan2(r1, -r3),
        math.atan2(r2, -r3),
        (r1 * d3 - r3 * d1) / qy if qy > 0.0 else 0.0,
        (r2 * d3 - r3 * d2) / qx if qx > 0.0 else 0.0,
    )


def cable_from_spherical(
    alpha: float, beta: float, alpha_rate: float = 0.0, beta_rate: float = 0.0
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(r, r') from the spherical angles (alpha, beta) and their rates (errata E16)."""
    sa, ca = math.sin(alpha), math.cos(alpha)
    sb, cb = math.sin(beta), math.cos(beta)
    r = (sa * cb, sa * sb, -ca)
    ea = (ca * cb, ca * sb, sa)
    eb = (-sb, cb, 0.0)
    k = beta_rate * sa
    rd = (alpha_rate * ea[0] + k * eb[0], alpha_rate * ea[1] + k * eb[1], alpha_rate * ea[2] + k * eb[2])
    return r, rd


def cable_from_planar(
    alpha_y: float, alpha_x: float, alpha_y_rate: float = 0.0, alpha_x_rate: float = 0.0
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(r, r') from the planar swing angles (alpha_y, alpha_x) and rates, inverse of :func:`planar_swing`.

    ``r`` is proportional to ``(tan alpha_y, tan alpha_x, -1)``; valid for |alpha_x|, |alpha_y| < pi/2.
    """
    ty, tx = math.tan(alpha_y), math.tan(alpha_x)
    dty = alpha_y_rate / math.cos(alpha_y) ** 2
    dtx = alpha_x_rate / math.cos(alpha_x) ** 2
    n = math.sqrt(1.0 + ty * ty + tx * tx)
    r = (ty / n, tx / n, -1.0 / n)
    dn = (ty * dty + tx * dtx) / n
    rd = ((dty * n - ty * dn) / (n * n), (dtx * n - tx * dn) / (n * n), dn / (n * n))
    return r, rd


def swing_amplitude(alpha_x: float, alpha_y: float, alpha_x_rate: float, alpha_y_rate: float, w2: float) -> float:
    """The swing amplitude (rad) of planar angles and rates (rad, rad/s): the angle an undamped small-angle pendulum
    of squared frequency ``w2`` (``g / l``, 1/s^2) would reach from this angle and rate, both axes together,
    ``sqrt(a_x^2 + a_y^2 + (a_x'^2 + a_y'^2) / w2)``; constant along such a pendulum's swing. The live loop's settle
    criterion after a reference's end (``offboard.flight.loop``) and its report (``offboard.flight.flight_outputs``)."""
    a2 = alpha_x * alpha_x + alpha_y * alpha_y
    return math.sqrt(a2 + (alpha_x_rate * alpha_x_rate + alpha_y_rate * alpha_y_rate) / w2)


def cable_pull(
    m_over_M: float,
    length: float,
    a: float,
    a_rate: float,
    a_other: float,
    a_other_rate: float,
    tilt: float,
    u_along: float,
    u_other: float,
    g_plus_uz: float,
) -> tuple[float, float, float, float]:
    """The cable's pull on the vehicle along one world axis as the accelerometer sees it, for a sensorless filter's
    swing (an extended Kalman filter's measurement and its slopes): ``(h, dh/da, dh/da', dh/dn)``, m/s^2 per rad
    (per rad/s for ``a'``). ``a``, ``a_rate``: the planar swing on this axis (``alpha_y`` for x, ``alpha_x`` for y)
    and its rate (rad, rad/s); ``a_other``, ``a_other_rate``: the other axis's; ``tilt``: the vehicle's world tilt
    on this axis (``n``, rad); ``u_along``, ``u_other``: the vehicle's measured acceleration on this and the other
    world axis, ``g_plus_uz`` its vertical specific force ``g + u_z`` (m/s^2); ``m_over_M``: load over vehicle mass;
    ``length``: the line (m).

    The body-horizontal specific force, heading-rotated, is ``(T / M) sin(a + n)``: the cable, ``a`` from the
    vertical, seen from a body tilted by ``n``. The tension is the pendulum's own, from the pivot's measured
    acceleration ``u``: ``T / m = -(u + g e3) . r + l |r'|^2``, here ``(g + u_z) cos a cos a_o - u sin a - u_o sin a_o
    + l (a'^2 + a_o'^2)``, and ``0`` on a slack line (then the pull says nothing of the swing). The gain used before,
    ``m / M`` times the vertical specific force, holds in a steady hover only: a vehicle that accelerates towards
    its load (10 m/s^2 while taking over a load swinging 24 deg) halves the tension while its thrust grows, and that
    gain, 2.3 times too large, turned the swing estimate's sign (docs/estimation.md, the take-over). The slopes
    include the tension's: accelerating, it is the tension, not the angle, that moves the pull most."""
    sa, ca = math.sin(a), math.cos(a)
    so, co = math.sin(a_other), math.cos(a_other)
    spin = length * (a_rate * a_rate + a_other_rate * a_other_rate)  # the centripetal part, m/s^2
    t_over_m = g_plus_uz * ca * co - u_along * sa - u_other * so + spin
    if not t_over_m > 0.0:
        return 0.0, 0.0, 0.0, 0.0
    gain = m_over_M * t_over_m
    s, c = math.sin(a + tilt), math.cos(a + tilt)
    dgain_da = m_over_M * (-g_plus_uz * sa * co - u_along * ca)
    dgain_dad = m_over_M * 2.0 * length * a_rate
    return gain * s, gain * c + dgain_da * s, dgain_dad * s, gain * c
