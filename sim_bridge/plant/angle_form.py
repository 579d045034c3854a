"""The paper's printed (alpha, beta) model, equations (12)-(24), for cross-checks only.

This is NOT the plant: it is singular at alpha = 0 (the rest position, errata E16), so the simulation
integrates the unit-sphere form in :mod:`sim_bridge.plant.dynamics`. It exists so that tests can prove the sphere
form and the printed equations describe the same system. Each ``g_*`` / ``f_*`` below is transcribed term by
term from the paper, with the errata applied:

- conventions C1-C4 (world z up, ZYX Euler, ``r = [S_a C_b, S_a S_b, -C_a]`` (E1), rotation law (13));
- the opening parenthesis lost in the second line of (15) restored (E2):
  ``- m C_b S_b (C_psi S_phi - C_phi S_psi S_theta)(C_a^2 - 1) / (M M_t)``.

Angle state (16 floats, SI): ``[x, y, z, x', y', z', phi, theta, psi, phi', theta', psi', alpha, beta,
alpha', beta']`` (m, m/s, rad, rad/s), world NWU. Input: the plant's input vector (only thrust, N, and
body torques tau_phi, tau_theta, tau_psi, N m, are used; the paper has no external forces).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from estimators.model.cable import cable_from_spherical, swing_angles
from sim_bridge.plant.dynamics import PlantParams

ANGLE_STATE_SIZE = 16


def angle_derivative(t: float, xa: Sequence[float], u: Sequence[float], p: PlantParams) -> list[float]:
    """Time derivative of the angle state by the printed equations (12)-(24). Singular at sin(alpha) = 0.

    Rotation uses (13) ``eta'' = tau / I`` whatever ``p.rigid_body`` says (the paper's model).
    """
    M, m, l, g = p.M, p.m, p.l, p.g
    Mt = M + m
    phi, theta, psi = xa[6], xa[7], xa[8]
    a, b, da, db = xa[12], xa[13], xa[14], xa[15]
    Sf, Cf = math.sin(phi), math.cos(phi)
    St, Ct = math.sin(theta), math.cos(theta)
    Sp, Cp = math.sin(psi), math.cos(psi)
    Sa, Ca = math.sin(a), math.cos(a)
    Sb, Cb = math.sin(b), math.cos(b)
    # The two groupings the paper uses: n1 and -n2 (errata C2).
    A1 = Sf * Sp + Cf * Cp * St
    A2 = Cp * Sf - Cf * Sp * St
    MMt = M * Mt

    # (15)
    g_x = (
        A1 * (M + m - m * Sa**2 + m * Sa**2 * Sb**2) / MMt
        - m * Cb * Sb * A2 * (Ca**2 - 1.0) / MMt
        + m * Ca * Cb * Cf * Sa * Ct / MMt
    )
    # (16)
    f_x = m * l * Cb * Sa * (da**2 - db**2 * Ca**2 + db**2) / Mt
    # (17)
    g_y = (
        m * Cb * Sb * A1 * (Ca**2 - 1.0) / MMt
        - A2 * (M + m - m * Sa**2 * Sb**2) / MMt
        + m * Ca * Cf * Sa * Sb * Ct / MMt
    )
    # (18)
    f_y = m * l * Sa * Sb * (da**2 + db**2 * Sa**2) / Mt
    # (19)
    g_z = Cf * Ct * (m * Sa**2 + M) / MMt + m * Ca * Cb * Sa * A1 / MMt - m * Ca * Sa * Sb * A2 / MMt
    # (20)
    f_z = -(m * l * da**2 * Ca - m * l * db**2 * Ca**3 + m * l * db**2 * Ca + M * g + g * m) / Mt
    # (21)
    g_a = Ca * Sb * A2 / (M * l) - Ca * Cb * A1 / (M * l) - Cf * Sa * Ct / (M * l)
    # (22)
    f_a = db**2 * math.sin(2.0 * a) / 2.0
    # (23)
    g_b = Cb * A2 / (M * l * Sa) + Sb * A1 / (M * l * Sa)
    # (24)
    f_b = -2.0 * da * db * Ca / Sa

    thrust = u[0]
    return [
        xa[3],
        xa[4],
        xa[5],
        g_x * thrust + f_x,
        g_y * thrust + f_y,
        g_z * thrust + f_z,
        xa[9],
        xa[10],
        xa[11],
        u[1] / p.I_phi,
        u[2] / p.I_theta,
        u[3] / p.I_psi,
        da,
        db,
        g_a * thrust + f_a,
        g_b * thrust + f_b,
    ]


def angle_to_sphere_state(xa: Sequence[float]) -> list[float]:
    """Angle state (16) -> plant state (18): ``r = [S_a C_b, S_a S_b, -C_a]``, ``r' = a' e_a + b' S_a e_b``."""
    r, rd = cable_from_spherical(xa[12], xa[13], xa[14], xa[15])
    return [*map(float, xa[:12]), *r, *rd]


def sphere_to_angle_state(x: Sequence[float]) -> list[float]:
    """Plant state (18) -> angle state (16), alpha in [0, pi]; beta is undefined (0) at alpha = 0."""
    s = swing_angles(x[12], x[13], x[14], x[15], x[16], x[17])
    return [*map(float, x[:12]), s.alpha, s.beta, s.alpha_rate, s.beta_rate]


def angle_accelerations_from_sphere(x: Sequence[float], xdot: Sequence[float]) -> tuple[float, float]:
    """(alpha'', beta'') implied by a plant state and its derivative (rad/s^2); needs sin(alpha) != 0.

    Differentiating ``r' = a' e_a + b' S_a e_b`` gives
    ``r'' = (a'' - b'^2 S_a C_a) e_a + (b'' S_a + 2 a' b' C_a) e_b - (a'^2 + b'^2 S_a^2) r``; projecting on
    the tangent basis gives ``a'' = r''.e_a + b'^2 S_a C_a`` and ``b'' = (r''.e_b - 2 a' b' C_a) / S_a``.
    """
    s = swing_angles(x[12], x[13], x[14], x[15], x[16], x[17])
    sa, ca = math.sin(s.alpha), math.cos(s.alpha)
    sb, cb = math.sin(s.beta), math.cos(s.beta)
    ea = (ca * cb, ca * sb, sa)
    eb = (-sb, cb, 0.0)
    rdd = xdot[15:18]
    rea = rdd[0] * ea[0] + rdd[1] * ea[1] + rdd[2] * ea[2]
    reb = rdd[0] * eb[0] + rdd[1] * eb[1]
    da, db = s.alpha_rate, s.beta_rate
    return rea + db * db * sa * ca, (reb - 2.0 * da * db * ca) / sa
