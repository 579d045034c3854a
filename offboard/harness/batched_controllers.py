"""The controllers of the batched sweep path (``offboard.harness.batched``) over many runs at once: the sliding-mode law
``offboard.control.smc.step`` (:func:`smc_step`), the stock cascade ``offboard.control.controllers.cascade``
(:class:`CascadeStep`; behind a shaped reference, ``zv`` / ``zvd``) and the swing-feedback cascade
(:class:`SwingFeedbackStep`) and LQR (:class:`LqrStep`) with the same expressions in the same order, the
runs' estimates and memories as arrays (``tests/test_sweep.py`` checks them against the scalar path).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators.filters.batched_kf import wrap_angles
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.controllers.cascade import CascadeGains
from offboard.control.controllers.lqr import LqrController
from offboard.control.controllers.swing_feedback import SwingFeedbackCascade

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


#: the estimate's named scalars (``ControlState`` after ``fx`` and ``fy``), whose sum with the chains' screens a run
_SCALARS = ControlState._fields[2:]


class BatchedBaseline:
    """What the batched baselines share: each run's time of its last step (its ``dt``), and a run whose estimate
    is not finite (``ControlState.is_finite``) gets the nominal hover command and keeps its memory, as the scalar
    laws do. Subclasses give :meth:`step`."""

    def __init__(self, vehicle: Vehicle, runs: int) -> None:
        self.vehicle = vehicle
        self.hover = vehicle.hover_thrust
        self.t_last = np.full(runs, np.nan)

    def step(
        self, t: float, dt: Array, finite: Array, est: dict[str, Array], refs: tuple[tuple[float, ...], ...]
    ) -> tuple[Array, Array]:
        """(u (4, B), saturated (B,)); keep memory only where ``finite``."""
        raise NotImplementedError

    def __call__(
        self,
        t: float,
        est: dict[str, Array],
        rfx: tuple[float, ...],
        rfy: tuple[float, ...],
        rz: tuple[float, ...],
        rpsi: tuple[float, ...],
    ) -> tuple[Array, Array]:
        """(u (4, B): thrust and torques, saturated (B,) bool) at time ``t`` (s) for the runs' estimates and the
        one reference (orders 0..6 of ``F_x``, ``F_y``; ``z``, ``psi``)."""
        finite = np.isfinite(est["fx"].sum(axis=0) + est["fy"].sum(axis=0) + sum(est[n] for n in _SCALARS))
        dt = np.where(np.isnan(self.t_last), 0.0, np.maximum(0.0, t - self.t_last))
        u, sat = self.step(t, dt, finite, est, (rfx, rfy, rz, rpsi))
        self.t_last = np.where(finite, t, self.t_last)
        return np.where(finite, u, np.array([[self.hover], [0.0], [0.0], [0.0]])), finite & sat


class CascadeStep(BatchedBaseline):
    """``offboard.control.controllers.cascade.CascadeController.step`` over runs (the swing-unaware stock cascade:
    position P, velocity PID, thrust vector with PX4's tilt limit, attitude P, rate PI), with the same expressions
    in the same order. Its memory: the velocity integrators, the rate integrators and each run's time of its last
    step (a run whose estimate is not finite gets the hover command and keeps its memory, as the scalar law
    does)."""

    def __init__(self, vehicle: Vehicle, gains: CascadeGains, runs: int) -> None:
        super().__init__(vehicle, runs)
        self.gains = gains
        self.l = vehicle.cable_length
        self.mt, self.m = vehicle.total_mass, vehicle.mass_load
        self.acc_gain = vehicle.gravity / vehicle.mass_vehicle
        self.g = vehicle.gravity
        self.thrust_max = vehicle.thrust_max
        self.torque_max = (vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max)
        zeros = np.zeros(runs)
        self.ivx, self.ivy, self.ivz, self.i_p, self.i_q = (zeros.copy() for _ in range(5))

    def offsets(self, dt: Array, est: dict[str, Array], finite: Array) -> tuple[Array | float, ...]:
        """The horizontal position, velocity and acceleration setpoint offsets (x, y each; world): none for the
        stock cascade (``CascadeController.offsets``; the swing-feedback baseline's hook)."""
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0

    def step(
        self, t: float, dt: Array, finite: Array, est: dict[str, Array], refs: tuple[tuple[float, ...], ...]
    ) -> tuple[Array, Array]:
        """The cascade's step (saturated: a torque, the thrust or the tilt limit)."""
        rfx, rfy, rz, rpsi = refs
        G = self.gains
        fx, fy = est["fx"], est["fy"]
        l = self.l
        x, y = fx[0] - l * est["alpha_y"], fy[0] - l * est["alpha_x"]
        vx, vy = fx[1] - l * est["alpha_y_rate"], fy[1] - l * est["alpha_x_rate"]
        ox, oy, ovx, ovy, oax, oay = self.offsets(dt, est, finite)
        # 1. position P + velocity feed-forward, speed limited
        vsx = rfx[1] + ovx + G.kp_xy * (rfx[0] + ox - x)
        vsy = rfy[1] + ovy + G.kp_xy * (rfy[0] + oy - y)
        vsz = rz[1] + G.kp_z * (rz[0] - est["z"])
        sp = np.hypot(vsx, vsy)
        over = sp > G.vel_max_xy
        scale = np.where(over, G.vel_max_xy / np.where(over, sp, 1.0), 1.0)
        vsx, vsy = np.where(over, vsx * scale, vsx), np.where(over, vsy * scale, vsy)
        vsz = np.maximum(-G.vel_max_z, np.minimum(G.vel_max_z, vsz))
        # 2. velocity PID + acceleration feed-forward (D on the first-order acceleration)
        evx, evy, evz = vsx - vx, vsy - vy, vsz - est["z_rate"]
        ivx, ivy, ivz = self.ivx + evx * dt, self.ivy + evy * dt, self.ivz + evz * dt
        phi, theta, psi = est["phi"], est["theta"], est["psi"]
        cps, sps = np.cos(psi), np.sin(psi)
        nx = theta * cps + phi * sps
        ny = theta * sps - phi * cps
        acc_x = self.acc_gain * (self.mt * nx + self.m * est["alpha_y"])
        acc_y = self.acc_gain * (self.mt * ny + self.m * est["alpha_x"])
        ax = rfx[2] + oax + G.kv_xy * evx + G.ki_xy * ivx - G.kd_xy * (acc_x - rfx[2])
        ay = rfy[2] + oay + G.kv_xy * evy + G.ki_xy * ivy - G.kd_xy * (acc_y - rfy[2])
        az = rz[2] + G.kv_z * evz + G.ki_z * ivz
        # 3. thrust vector, tilt limited as PX4 does (cascade.AttitudeThrustLoop)
        tz = np.maximum(az + self.g, 0.1 * self.g)
        h = np.hypot(ax, ay)
        h_max = tz * math.tan(G.tilt_max)
        tilted = h > h_max
        shrink = np.where(tilted, h_max / np.where(tilted, h, 1.0), 1.0)
        ax, ay = np.where(tilted, ax * shrink, ax), np.where(tilted, ay * shrink, ay)
        thrust = self.mt * np.sqrt(ax * ax + ay * ay + tz * tz)
        psi_d = rpsi[0]
        cp, sp_ = math.cos(psi_d), math.sin(psi_d)
        zx, zy = cp * ax + sp_ * ay, -sp_ * ax + cp * ay
        norm = np.sqrt(zx * zx + zy * zy + tz * tz)
        phi_d = np.arcsin(np.maximum(-1.0, np.minimum(1.0, -zy / norm)))
        theta_d = np.arctan2(zx, tz)
        # 4. attitude P -> rates, rate PI -> angular acceleration -> torque
        p_sp = G.kp_att * (phi_d - phi)
        q_sp = G.kp_att * (theta_d - theta)
        ref_rate = rpsi[1] if len(rpsi) > 1 else 0.0
        r_sp = ref_rate + G.kp_yaw * wrap_angles(psi_d - psi)
        r_sp = np.maximum(-G.yaw_rate_max, np.minimum(G.yaw_rate_max, r_sp))
        e_p, e_q = p_sp - est["phi_rate"], q_sp - est["theta_rate"]
        i_p, i_q = self.i_p + e_p * dt, self.i_q + e_q * dt
        Ix, Iy, Iz = self.vehicle.inertia
        tau_phi = Ix * (G.kr_rp * e_p + G.ki_rp * i_p)
        tau_theta = Iy * (G.kr_rp * e_q + G.ki_rp * i_q)
        tau_psi = Iz * (G.kr_yaw * (r_sp - est["psi_rate"]) + (rpsi[2] if len(rpsi) > 2 else 0.0))
        tp, tt, ts = self.torque_max
        s_p, s_q, s_r = np.abs(tau_phi) > tp, np.abs(tau_theta) > tt, np.abs(tau_psi) > ts
        s_t = thrust > self.thrust_max
        tau_phi = np.where(s_p, np.copysign(tp, tau_phi), tau_phi)
        tau_theta = np.where(s_q, np.copysign(tt, tau_theta), tau_theta)
        tau_psi = np.where(s_r, np.copysign(ts, tau_psi), tau_psi)
        thrust = np.where(s_t, self.thrust_max, thrust)
        # the memories, as the scalar law keeps them (runs with a non-finite estimate keep theirs)
        self.i_p = np.where(finite & ~s_p, i_p, self.i_p)
        self.i_q = np.where(finite & ~s_q, i_q, self.i_q)
        self.ivx = np.where(finite & ~tilted, ivx, self.ivx)
        self.ivy = np.where(finite & ~tilted, ivy, self.ivy)
        self.ivz = np.where(finite & (thrust < self.thrust_max), ivz, self.ivz)
        return np.stack([thrust, tau_phi, tau_theta, tau_psi]), s_p | s_q | s_r | s_t | tilted


class SwingFeedbackStep(CascadeStep):
    """``offboard.control.controllers.swing_feedback.SwingFeedbackCascade`` over runs: the cascade plus the
    ArduPilot slung-payload applet's offsets toward the load, the same expressions (each run's rest offset,
    position offset and velocity offset as arrays; runs with a non-finite estimate keep theirs)."""

    def __init__(self, vehicle: Vehicle, gains: CascadeGains, runs: int, law: SwingFeedbackCascade) -> None:
        super().__init__(vehicle, gains, runs)
        self.vel_p, self.wp_pos_p, self.rest_tc, self.dist_max = law.vel_p, law.wp_pos_p, law.rest_tc, law.dist_max
        zeros = np.zeros(runs)
        self.rest_x, self.rest_y, self.off_x, self.off_y, self.vel_x, self.vel_y = (zeros.copy() for _ in range(6))

    def offsets(self, dt: Array, est: dict[str, Array], finite: Array) -> tuple[Array | float, ...]:
        dx, dy = self.l * est["alpha_y"], self.l * est["alpha_x"]  # payload - vehicle, horizontal (m, world)
        alpha = dt / (dt + self.rest_tc / (2.0 * math.pi))
        rest_x = self.rest_x + alpha * (dx - self.rest_x)
        rest_y = self.rest_y + alpha * (dy - self.rest_y)
        ox, oy = self.off_x + self.vel_x * dt, self.off_y + self.vel_y * dt
        far = np.hypot(dx, dy) > self.dist_max
        vel_x = np.where(far, 0.0, self.wp_pos_p * (-ox - rest_x))
        vel_y = np.where(far, 0.0, self.wp_pos_p * (-oy - rest_y))
        self.rest_x, self.rest_y = np.where(finite, rest_x, self.rest_x), np.where(finite, rest_y, self.rest_y)
        self.off_x, self.off_y = np.where(finite, ox, self.off_x), np.where(finite, oy, self.off_y)
        self.vel_x, self.vel_y = np.where(finite, vel_x, self.vel_x), np.where(finite, vel_y, self.vel_y)
        oax = np.where(far, 0.0, -self.vel_p * est["fx"][3])
        oay = np.where(far, 0.0, -self.vel_p * est["fy"][3])
        return ox, oy, vel_x, vel_y, oax, oay


class LqrStep(BatchedBaseline):
    """``offboard.control.controllers.lqr.LqrController.step`` over runs: the reference state from the flat
    reference, the errors turned into the heading frame, ``du = -K e`` summed in the scalar law's order, the
    integrals held while anything saturates, the motors' lag modelled on the law's own commands. Its memory: the
    four integrals, the modelled delivered thrust and torques, the last commands and each run's last step time (a
    run whose estimate is not finite gets the hover command and keeps them)."""

    def __init__(self, law: LqrController, runs: int) -> None:
        super().__init__(law.vehicle, runs)
        self.k = law.K.tolist()  # python floats: the scalar law's products, to the bit
        self.kf = law.kf
        self.thrust_max, self.torque_max = law.thrust_max, law.torque_max
        self.ints = [np.zeros(runs) for _ in range(4)]
        self.lag_s = law.lag_s
        self.delivered = [np.full(runs, np.nan) for _ in range(4)]  # NaN: before the run's first step
        self.sent = [np.zeros(runs) for _ in range(4)]

    def step(
        self, t: float, dt: Array, finite: Array, est: dict[str, Array], refs: tuple[tuple[float, ...], ...]
    ) -> tuple[Array, Array]:
        """The LQR step (saturated: the thrust or a torque)."""
        rfx, rfy, rz, rpsi = refs
        v = self.vehicle
        fx, fy = est["fx"], est["fy"]
        k = self.kf
        l, g, c, w2 = k.l, k.g, k.c, k.omega2
        ay_r, ay_rd = -rfx[2] / g, -rfx[3] / g
        ax_r, ax_rd = -rfy[2] / g, -rfy[3] / g
        x_r, vx_r = rfx[0] - l * ay_r, rfx[1] - l * ay_rd
        y_r, vy_r = rfy[0] - l * ax_r, rfy[1] - l * ax_rd
        nx_r, nxd_r, nxdd_r = rfx[4] / c - ay_r, rfx[5] / c - ay_rd, (rfx[6] + w2 * rfx[4]) / c
        ny_r, nyd_r, nydd_r = rfy[4] / c - ax_r, rfy[5] / c - ax_rd, (rfy[6] + w2 * rfy[4]) / c
        x, y = fx[0] - l * est["alpha_y"], fy[0] - l * est["alpha_x"]
        vx, vy = fx[1] - l * est["alpha_y_rate"], fy[1] - l * est["alpha_x_rate"]
        psi = est["psi"]
        cp, sp = np.cos(psi), np.sin(psi)

        def rot(a: Any, b: Any) -> tuple[Array, Array]:
            return cp * a + sp * b, -sp * a + cp * b

        ex, ey = rot(x - x_r, y - y_r)
        evx, evy = rot(vx - vx_r, vy - vy_r)
        eay, eax = rot(est["alpha_y"] - ay_r, est["alpha_x"] - ax_r)
        eayd, eaxd = rot(est["alpha_y_rate"] - ay_rd, est["alpha_x_rate"] - ax_rd)
        th_r, mphi_r = rot(nx_r, ny_r)
        thd_r, mphid_r = rot(nxd_r, nyd_r)
        thdd_r, mphidd_r = rot(nxdd_r, nydd_r)
        ez, evz = est["z"] - rz[0], est["z_rate"] - rz[1]
        epsi, er = wrap_angles(psi - rpsi[0]), est["psi_rate"] - rpsi[1]
        i = self.ints
        ints = [i[0] + ex * dt, i[1] + ey * dt, i[2] + ez * dt, i[3] + epsi * dt]
        Ix, Iy, Iz = v.inertia
        ff = (v.total_mass * (g + rz[2]), -Ix * mphidd_r, Iy * thdd_r, Iz * rpsi[2])
        lagged: tuple[Array, ...] = ()
        if self.lag_s > 0.0:  # the motors' state, as the scalar law models it
            first = np.isnan(self.delivered[0])
            a = np.where(dt > 0.0, 1.0 - np.exp(-dt / self.lag_s), 0.0)
            delivered = [np.where(first, f, dj + a * (sj - dj)) for dj, sj, f in zip(self.delivered, self.sent, ff)]
            self.delivered = [np.where(finite, n, o) for n, o in zip(delivered, self.delivered)]
            lagged = tuple(dj - fj for dj, fj in zip(delivered, ff))
        e = (
            ex,
            ey,
            ez,
            evx,
            evy,
            evz,
            est["phi"] + mphi_r,
            est["theta"] - th_r,
            epsi,
            est["phi_rate"] + mphid_r,
            est["theta_rate"] - thd_r,
            er,
            eay,
            eax,
            eayd,
            eaxd,
            *ints,
            *lagged,
        )
        du = []
        for row in self.k:  # Python's sum over the row, in its order (0 + k0 e0 + k1 e1 + ...)
            acc: Any = 0
            for kj, ej in zip(row, e):
                acc = acc + kj * ej
            du.append(-acc)
        thrust = ff[0] + du[0]
        tau_phi = ff[1] + du[1]
        tau_theta = ff[2] + du[2]
        tau_psi = ff[3] + du[3]
        sat = (thrust > self.thrust_max) | (thrust < 0.0)
        thrust = np.minimum(np.maximum(thrust, 0.0), self.thrust_max)
        tp, tt, ts = self.torque_max
        sat = sat | (np.abs(tau_phi) > tp) | (np.abs(tau_theta) > tt) | (np.abs(tau_psi) > ts)
        u = np.stack(
            [
                thrust,
                np.maximum(-tp, np.minimum(tp, tau_phi)),
                np.maximum(-tt, np.minimum(tt, tau_theta)),
                np.maximum(-ts, np.minimum(ts, tau_psi)),
            ]
        )
        keep = finite & ~sat
        self.ints = [np.where(keep, new, old) for new, old in zip(ints, i)]
        self.sent = [np.where(finite, n, o) for n, o in zip(u, self.sent)]
        return u, sat
