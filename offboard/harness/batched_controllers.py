"""The controllers of the batched sweep path (``offboard.harness.batched``) over many runs at once: the sliding-mode law
``offboard.control.smc.step`` (:func:`smc_step`) with the same expressions in the same order, the runs' estimates and
memories as arrays (``tests/test_sweep.py`` checks them against the scalar path).
"""

from __future__ import annotations

import math

import numpy as np

from estimators.model.flatness import flat_constants
from offboard.control import smc

Array = np.ndarray


def _sw(s: Array, smooth: bool, eps: float) -> Array:
    return s / (np.abs(s) + eps) if smooth else np.sign(s)


def smc_step(
    dt: float,
    est: dict[str, Array],
    rfx: tuple[float, ...],
    rfy: tuple[float, ...],
    rz: tuple[float, ...],
    rpsi: tuple[float, ...],
    memory: Array,
    params: smc.ControllerParams,
) -> tuple[Array, Array, Array]:
    """``offboard.control.smc.step`` over runs (one reference for all): returns (u (4, B): thrust and torques,
    saturated (B,) bool, the new memory (8, B): int_z, int_psi, int_fx, int_fy and the actuation model's
    tau_phi_cmd, tau_theta_cmd, tau_phi_act, tau_theta_act). ``dt``: time since the previous tick (0 at the
    first). Non-finite inputs are not screened here (the runs start finite; a diverging run is reported by the
    plant's state)."""
    v = params.vehicle
    k = flat_constants(v)
    G = params.gains
    smooth = params.switching == "smooth"
    eps_z, eps_psi, eps_f = params.layers()
    M, m, Mt = v.mass_vehicle, v.mass_load, v.total_mass
    Ip, It, Is = v.inertia
    cos_max = math.cos(params.max_tilt)
    phi, theta, psi = est["phi"], est["theta"], est["psi"]
    sf, cf, st, ct, sp, cp = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta), np.sin(psi), np.cos(psi)
    n1 = sf * sp + cf * cp * st
    n2 = cf * sp * st - cp * sf
    n3 = cf * ct
    # cable_from_planar over runs
    ty, tx = np.tan(est["alpha_y"]), np.tan(est["alpha_x"])
    dty = est["alpha_y_rate"] / np.cos(est["alpha_y"]) ** 2
    dtx = est["alpha_x_rate"] / np.cos(est["alpha_x"]) ** 2
    nn = np.sqrt(1.0 + ty * ty + tx * tx)
    r1, r2, r3 = ty / nn, tx / nn, -1.0 / nn
    dn = (ty * dty + tx * dtx) / nn
    d1, d2, d3 = (dty * nn - ty * dn) / (nn * nn), (dtx * nn - tx * dn) / (nn * nn), dn / (nn * nn)
    nr = n1 * r1 + n2 * r2 + n3 * r3
    g_z = (Mt * np.maximum(n3, cos_max) - m * nr * r3) / (M * Mt)
    f_z = m * k.l * (d1 * d1 + d2 * d2 + d3 * d3) * r3 / Mt - k.g
    e_z = est["z"] - rz[0]
    e_zd = est["z_rate"] - rz[1]
    int_z = memory[0] + e_z * dt
    s_z = e_zd + G.lambda1 * e_z + G.lambda0 * int_z
    thrust = (rz[2] - f_z - G.lambda1 * e_zd - G.lambda0 * e_z - G.rho_z * _sw(s_z, smooth, eps_z)) / np.maximum(
        g_z, 1e-3
    )
    two_pi = 2.0 * math.pi
    a = np.fmod(psi - rpsi[0] + math.pi, two_pi)  # estimators.model.frames.wrap_angle over runs
    e_psi = np.where(a <= 0.0, a + two_pi, a) - math.pi
    e_psid = est["psi_rate"] - rpsi[1]
    int_psi = memory[1] + e_psi * dt
    s_psi = e_psid + G.gamma1 * e_psi + G.gamma0 * int_psi
    tau_psi = Is * (rpsi[2] - G.gamma1 * e_psid - G.gamma0 * e_psi - G.rho_psi * _sw(s_psi, smooth, eps_psi))
    K0, K1, K2, K3, K4, K5 = G.K
    fx, fy = est["fx"], est["fy"]
    ex = [fx[i] - rfx[i] for i in range(6)]
    ey = [fy[i] - rfy[i] for i in range(6)]
    int_fx = memory[2] + ex[0] * dt
    int_fy = memory[3] + ey[0] * dt
    sig_x = ex[5] + K5 * ex[4] + K4 * ex[3] + K3 * ex[2] + K2 * ex[1] + K1 * ex[0] + K0 * int_fx
    sig_y = ey[5] + K5 * ey[4] + K4 * ey[3] + K3 * ey[2] + K2 * ey[1] + K1 * ey[0] + K0 * int_fy
    vx = (
        rfx[6]
        - K5 * ex[5]
        - K4 * ex[4]
        - K3 * ex[3]
        - K2 * ex[2]
        - K1 * ex[1]
        - K0 * ex[0]
        - G.rho_F * _sw(sig_x, smooth, eps_f)
    )
    vy = (
        rfy[6]
        - K5 * ey[5]
        - K4 * ey[4]
        - K3 * ey[3]
        - K2 * ey[2]
        - K1 * ey[1]
        - K0 * ey[0]
        - G.rho_F * _sw(sig_y, smooth, eps_f)
    )
    nddx = (vx + k.omega2 * fx[4]) / k.c
    nddy = (vy + k.omega2 * fy[4]) / k.c
    lag = params.actuation_lag_s
    tp_act = tt_act = np.zeros_like(nddx)
    if lag > 0.0:  # offboard.control.smc.step's actuation lag, the same expressions
        a = 1.0 - math.exp(-dt / lag) if dt > 0.0 else 0.0
        tp_act = memory[6] + a * (memory[4] - memory[6])
        tt_act = memory[7] + a * (memory[5] - memory[7])
        a1, a2 = tt_act / It, tp_act / Ip
        e6x = k.c * (cp * a1 + sp * a2) - k.omega2 * fx[4] - rfx[6]
        e6y = k.c * (sp * a1 - cp * a2) - k.omega2 * fy[4] - rfy[6]
        dvx = -K5 * e6x - K4 * ex[5] - K3 * ex[4] - K2 * ex[3] - K1 * ex[2] - K0 * ex[1]
        dvy = -K5 * e6y - K4 * ey[5] - K3 * ey[4] - K2 * ey[3] - K1 * ey[2] - K0 * ey[1]
        nddx = nddx + lag * (dvx + k.omega2 * fx[5]) / k.c
        nddy = nddy + lag * (dvy + k.omega2 * fy[5]) / k.c
    t1, t2 = theta, -phi
    t1d, t2d = est["theta_rate"], -est["phi_rate"]
    w = est["psi_rate"]
    wd = rpsi[2]
    t1dd = cp * nddx + sp * nddy + 2.0 * w * t2d + wd * t2 + w * w * t1
    t2dd = -sp * nddx + cp * nddy - 2.0 * w * t1d - wd * t1 + w * w * t2
    tau_theta = It * t1dd
    tau_phi = -Ip * t2dd
    lo, hi = params.thrust_min, params.thrust_max
    tp_max, tt_max, ts_max = params.torque_max
    s1 = (thrust < lo) | (thrust > hi)
    s2 = np.abs(tau_phi) > tp_max
    s3 = np.abs(tau_theta) > tt_max
    s4 = np.abs(tau_psi) > ts_max
    tau_phi, tau_theta = np.clip(tau_phi, -tp_max, tp_max), np.clip(tau_theta, -tt_max, tt_max)
    thrust = np.clip(thrust, lo, hi)
    if params.shared_roll_pitch:  # offboard.control.smc.step's shared roll / pitch margin, the same expressions
        share = np.abs(tau_phi) / tp_max + np.abs(tau_theta) / tt_max
        over = share > 1.0
        scale = np.where(over, share, 1.0)
        tau_phi, tau_theta, share = tau_phi / scale, tau_theta / scale, share / scale
        s2 = s2 | over
        t_lo, t_hi = smc.shared_thrust_range(params, share)  # arithmetic only: element-wise on the arrays
        s1 = s1 | (thrust < t_lo) | (thrust > t_hi)
        thrust = np.minimum(np.maximum(thrust, t_lo), t_hi)
    u = np.stack([thrust, tau_phi, tau_theta, np.clip(tau_psi, -ts_max, ts_max)])
    s23 = s2 | s3
    new_mem = np.stack(
        [
            np.where(s1, memory[0], int_z),
            np.where(s4, memory[1], int_psi),
            np.where(s23, memory[2], int_fx),
            np.where(s23, memory[3], int_fy),
            u[1],
            u[2],
            tp_act,
            tt_act,
        ]
    )
    return u, s1 | s2 | s3 | s4, new_mem
