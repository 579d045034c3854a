"""Flat outputs of the tangent-linearized model and the map between planar states and (F, F', ..., F^(5)).

Derivation: ``docs/model.md`` (errata C6, E9). With ``c = (M + m) g^2 / (M l)`` and, per horizontal axis,
the swing angle ``a`` (``alpha_y`` for world x, ``alpha_x`` for world y) and the thrust tilt ``n`` (the
horizontal component of the thrust direction to first order)::

    F      = p + l a                 (the load's horizontal position to first order)
    F'     = v + l a'
    F''    = -g a
    F'''   = -g a'
    F^(4)  = c (a + n)
    F^(5)  = c (a' + n')
    F^(6)  = c (n'' - (M + m) g / (M l) (a + n)) = c n'' - (M + m) g / (M l) F^(4)

Written in the world frame this chain holds for any constant heading psi: the tilt is
``n = Rz(psi) [theta, -phi]`` (x: ``theta C_psi + phi S_psi``, y: ``theta S_psi - phi C_psi``, errata C2),
which at psi = 0 gives the paper's X-Z chain (``F^(4) = c (theta + alpha_y)``) and Y-Z chain
(``F^(4) = c (alpha_x - phi)``) exactly (errata E9). The map lives in ``estimators`` because both the
estimators and the controller use it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from estimators.model.cable import planar_swing
from estimators.model.control_state import ControlState
from estimators.model.frames import wrap_angle
from estimators.model.vehicle import Vehicle


class FlatConstants(NamedTuple):
    """Constants of the flat-output chain (SI)."""

    l: float  # cable length, m
    g: float  # gravity, m/s^2
    c: float  # (M + m) g^2 / (M l), m/s^4 per rad
    omega2: float  # (M + m) g / (M l), the free swing frequency squared, 1/s^2


def flat_constants(vehicle: Vehicle) -> FlatConstants:
    """Chain constants from the controller's nominal vehicle."""
    l, g = vehicle.cable_length, vehicle.gravity
    omega2 = vehicle.total_mass * g / (vehicle.mass_vehicle * l)
    return FlatConstants(l, g, omega2 * g, omega2)


def world_tilt(
    phi: float, theta: float, psi: float, phi_rate: float, theta_rate: float, psi_rate: float
) -> tuple[float, float, float, float]:
    """First-order horizontal thrust tilt in the world frame and its rate: (n_x, n_y, n_x', n_y').

    ``n = Rz(psi) [theta, -phi]`` (rad), differentiated exactly including the heading rate.
    """
    cp, sp = math.cos(psi), math.sin(psi)
    nx = theta * cp + phi * sp
    ny = theta * sp - phi * cp
    nxd = theta_rate * cp + phi_rate * sp - psi_rate * ny
    nyd = theta_rate * sp - phi_rate * cp + psi_rate * nx
    return nx, ny, nxd, nyd


def flat_chain(
    k: FlatConstants, p: float, v: float, a: float, a_rate: float, n: float, n_rate: float
) -> tuple[float, float, float, float, float, float]:
    """(F, F', F'', F''', F^(4), F^(5)) of one horizontal axis from its planar state.

    p, v: vehicle position (m) and velocity (m/s) along the axis; a, a_rate: swing angle along the axis
    (alpha_y for x, alpha_x for y; rad, rad/s); n, n_rate: thrust tilt along the axis (rad, rad/s).
    """
    return (
        p + k.l * a,
        v + k.l * a_rate,
        -k.g * a,
        -k.g * a_rate,
        k.c * (a + n),
        k.c * (a_rate + n_rate),
    )


def planar_state(k: FlatConstants, chain: tuple[float, ...]) -> tuple[float, float, float, float, float, float]:
    """Inverse of :func:`flat_chain`: (p, v, a, a', n, n') from (F, ..., F^(5)) of one axis."""
    F0, F1, F2, F3, F4, F5 = chain[:6]
    a = -F2 / k.g
    a_rate = -F3 / k.g
    return (
        F0 + k.l * F2 / k.g,
        F1 + k.l * F3 / k.g,
        a,
        a_rate,
        F4 / k.c - a,
        F5 / k.c - a_rate,
    )


def control_state_of(
    k: FlatConstants, x: Sequence[float], ay: float, ax: float, ay_rate: float, ax_rate: float
) -> ControlState:
    """The controller's input from a state whose first 12 entries are the rigid body's (position m, velocity m/s,
    ZYX Euler angles rad, their rates rad/s; world NWU, the plant's and the 16-state linear model's order) and the
    planar swing angles ``ay`` (alpha_y), ``ax`` (alpha_x) and their rates (rad, rad/s)."""
    nx, ny, nxd, nyd = world_tilt(x[6], x[7], x[8], x[9], x[10], x[11])
    return ControlState(
        flat_chain(k, x[0], x[3], ay, ay_rate, nx, nxd),
        flat_chain(k, x[1], x[4], ax, ax_rate, ny, nyd),
        x[2],
        x[5],
        x[6],
        x[7],
        x[8],
        x[9],
        x[10],
        x[11],
        ax,
        ay,
        ax_rate,
        ay_rate,
    )


def truth_control_state(x: Sequence[float], k: FlatConstants) -> ControlState:
    """The controller's input computed from the true plant state (18 floats, ``sim_bridge.plant.dynamics`` order: the
    rigid body's 12, then the cable's unit vector and its rate; the paper's all-states-measured case)."""
    ay, ax, ayd, axd = planar_swing(x[12], x[13], x[14], x[15], x[16], x[17])
    return control_state_of(k, x, ay, ax, ayd, axd)


def control_state_from_tilt(
    k: FlatConstants,
    x_axis: Sequence[float],
    y_axis: Sequence[float],
    z: float,
    z_rate: float,
    psi: float,
    psi_rate: float,
) -> ControlState:
    """The controller's input from a filter's planar states: per world axis ``(p, v, a, a', n, n')`` (m, m/s, swing
    rad, rad/s, world tilt rad, rad/s; x: alpha_y and n_x, y: alpha_x and n_y), height (m) and its rate (m/s),
    heading (rad, wrapped here) and its rate (rad/s). The Euler angles and rates invert :func:`world_tilt`."""
    px, vx, ay, ayd, nx, nxd = x_axis[:6]
    py, vy, ax, axd, ny, nyd = y_axis[:6]
    cp, sp = math.cos(psi), math.sin(psi)
    theta = nx * cp + ny * sp
    phi = nx * sp - ny * cp
    theta_rate = nxd * cp + nyd * sp + psi_rate * (-nx * sp + ny * cp)
    phi_rate = nxd * sp - nyd * cp + psi_rate * (nx * cp + ny * sp)
    return ControlState(
        flat_chain(k, px, vx, ay, ayd, nx, nxd),
        flat_chain(k, py, vy, ax, axd, ny, nyd),
        z,
        z_rate,
        phi,
        theta,
        wrap_angle(psi),
        phi_rate,
        theta_rate,
        psi_rate,
        ax,
        ay,
        axd,
        ayd,
    )
