"""The baselines of a compiled run, one run at a time: the stock cascade (``cascade``, and ``zv`` / ``zvd`` behind a
reference shaped beforehand by the driver), the swing-feedback cascade (``swing-feedback``) and LQR with its
motor-lag states (``lqr``), in the order of the scalar controllers' expressions (``offboard.control.controllers``;
``tests/test_compiled_laws.py``). Their constants (indices ``C_*`` (cascade, swing-feedback) and ``Q_*`` (LQR), the
hover thrust ``BASE_HOVER`` first in both) come from the registry's own controllers; their memory's indices are
``B_*``. Frames and units as in the scalar path: model frame (world NWU, z up; body FLU), SI, rad. The screening of a
non-finite estimate and each baseline's own ``dt`` are :func:`.laws.law_step`'s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators import kernels as kern
from estimators.kernels import inline_kernel, maximum, minimum, pack_constants, pure_kernel, wrap_angle
from estimators.model.vehicle import Vehicle
from offboard.control.compiled import reference_row as lay

# ---- the baselines' constants: the hover thrust (N) first in both layouts ----------------------------------------
BASE_HOVER = 0
# the cascade (CascadeGains, controllers.cascade.CascadeController); C_TAN_TILT: tan of the tilt limit
C_KP_XY, C_KP_Z, C_KV_XY, C_KI_XY, C_KD_XY, C_KV_Z, C_KI_Z, C_VEL_MAX_XY, C_VEL_MAX_Z = range(1, 10)
C_TAN_TILT, C_KP_ATT, C_KP_YAW, C_KR_RP, C_KI_RP, C_KR_YAW, C_YAW_RATE_MAX = range(10, 17)
# the nominal vehicle: cable (m), masses (kg), g / M (m/s^2 per kg), g, limits (N, N m), inertia (kg m^2)
C_L, C_MT, C_MLOAD, C_ACC_GAIN, C_G, C_THRUST_MAX, C_TP, C_TT, C_TS, C_IX, C_IY, C_IZ = range(17, 29)
CASCADE_SIZE = 29
# swing-feedback's applet (SwingFeedbackCascade): SLUP_VEL_P (s), SLUP_WP_POS_P (1/s), the rest filter's
# rc = SLUP_RESTOFS_TC / 2 pi (s), SLUP_DIST_MAX (m)
C_VEL_P, C_WP_POS_P, C_REST_RC, C_DIST_MAX = range(29, 33)
SWING_SIZE = 33
# LQR: flat constants, total mass (kg), inertia, limits, the motors' lag in the design (s; 0: none)
Q_L, Q_G, Q_C, Q_W2, Q_MT, Q_IX, Q_IY, Q_IZ, Q_THRUST_MAX, Q_TP, Q_TT, Q_TS, Q_LAG = range(1, 14)
LQR_SIZE = 14

# ---- a run's memory --------------------------------------------------------------------------------------------------
# the baselines: the time of the last step (s; NaN before the first) first
B_T_LAST = 0
# the cascade's velocity integrators (m, world) and rate integrators (rad); swing-feedback's rest offset, position
# offset (m, world) and velocity offset (m/s)
B_IVX, B_IVY, B_IVZ, B_IP, B_IQ = range(1, 6)
CASCADE_MEMORY = 6
B_REST_X, B_REST_Y, B_OFF_X, B_OFF_Y, B_VEL_X, B_VEL_Y = range(6, 12)
SWING_MEMORY = 12
# LQR: the integrals of x, y (heading frame), z, heading (m s, rad s); the delivered thrust and torques it models
# (N, N m; NaN before the first step); its last commands. Then a scratch area, rewritten at every step (not memory:
# kept here so that the step allocates nothing, and indexed as an array: numba indexes a tuple by a loop variable
# through a switch, which made the gain's row sums 5x slower): the state error e (24) and the feed-forward u* (4)
B_INT, B_DELIVERED, B_SENT, LQR_STATE = 1, 5, 9, 13
B_ERROR, B_FF = 13, 37
LQR_MEMORY = 41


# ---- Python side: the constants and the initial memory ------------------------------------------------------------
def _cascade_constants(law: Any, vehicle: Vehicle) -> np.ndarray:
    """The cascade's constants from the registry's controller ``law`` (its gains) on the nominal ``vehicle``, and
    with a ``SwingFeedbackCascade`` the applet's."""
    from offboard.control.controllers.swing_feedback import SwingFeedbackCascade

    G = law.gains
    Ix, Iy, Iz = vehicle.inertia
    tp, tt, ts = vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max
    acc_gain = vehicle.gravity / vehicle.mass_vehicle
    values = {BASE_HOVER: vehicle.hover_thrust, C_KP_XY: G.kp_xy, C_KP_Z: G.kp_z, C_KV_XY: G.kv_xy, C_KI_XY: G.ki_xy}
    values.update({C_KD_XY: G.kd_xy, C_KV_Z: G.kv_z, C_KI_Z: G.ki_z, C_VEL_MAX_XY: G.vel_max_xy})
    values.update({C_VEL_MAX_Z: G.vel_max_z, C_TAN_TILT: math.tan(G.tilt_max), C_KP_ATT: G.kp_att})
    values.update({C_KP_YAW: G.kp_yaw, C_KR_RP: G.kr_rp, C_KI_RP: G.ki_rp, C_KR_YAW: G.kr_yaw})
    values.update({C_YAW_RATE_MAX: G.yaw_rate_max, C_L: vehicle.cable_length, C_MT: vehicle.total_mass})
    values.update({C_MLOAD: vehicle.mass_load, C_ACC_GAIN: acc_gain, C_G: vehicle.gravity})
    values.update({C_THRUST_MAX: vehicle.thrust_max, C_TP: tp, C_TT: tt, C_TS: ts, C_IX: Ix, C_IY: Iy, C_IZ: Iz})
    if not isinstance(law, SwingFeedbackCascade):
        return pack_constants(CASCADE_SIZE, values)
    # the applet's filter constant, computed as the scalar law computes it (a Python float, the same bits)
    values.update({C_VEL_P: law.vel_p, C_WP_POS_P: law.wp_pos_p, C_REST_RC: law.rest_tc / (2.0 * math.pi)})
    values.update({C_DIST_MAX: law.dist_max})
    return pack_constants(SWING_SIZE, values)


def _lqr_constants(law: Any) -> np.ndarray:
    """LQR's constants from the registry's ``LqrController`` (the nominal vehicle's figures and the design's motor
    lag)."""
    k, v = law.kf, law.vehicle
    Ix, Iy, Iz = v.inertia
    tp, tt, ts = law.torque_max
    values = {BASE_HOVER: v.hover_thrust, Q_L: k.l, Q_G: k.g, Q_C: k.c, Q_W2: k.omega2, Q_MT: v.total_mass}
    values.update({Q_IX: Ix, Q_IY: Iy, Q_IZ: Iz, Q_THRUST_MAX: law.thrust_max, Q_TP: tp, Q_TT: tt, Q_TS: ts})
    values.update({Q_LAG: law.lag_s})
    return pack_constants(LQR_SIZE, values)


# ---- the cascade: controllers.cascade.CascadeController (and SwingFeedbackCascade's offsets) ----------------------
@pure_kernel
def swing_offsets(c: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray) -> tuple[float, ...]:
    """``SwingFeedbackStep.offsets``: the applet's position (m), velocity (m/s) and acceleration (m/s^2) setpoint
    offsets, world (x, y each), its memory (``B_REST_*``, ``B_OFF_*``, ``B_VEL_*``) advanced by ``dt`` (s)."""
    dx, dy = c[C_L] * est[kern.EST_ALPHA_Y], c[C_L] * est[kern.EST_ALPHA_X]  # payload - vehicle, horizontal (m, world)
    alpha = dt / (dt + c[C_REST_RC])
    rest_x = mem[B_REST_X] + alpha * (dx - mem[B_REST_X])
    rest_y = mem[B_REST_Y] + alpha * (dy - mem[B_REST_Y])
    ox, oy = mem[B_OFF_X] + mem[B_VEL_X] * dt, mem[B_OFF_Y] + mem[B_VEL_Y] * dt
    far = math.hypot(dx, dy) > c[C_DIST_MAX]  # beyond SLUP_DIST_MAX the offsets stop growing
    vel_x = 0.0 if far else c[C_WP_POS_P] * (-ox - rest_x)
    vel_y = 0.0 if far else c[C_WP_POS_P] * (-oy - rest_y)
    mem[B_REST_X], mem[B_REST_Y], mem[B_OFF_X], mem[B_OFF_Y] = rest_x, rest_y, ox, oy
    mem[B_VEL_X], mem[B_VEL_Y] = vel_x, vel_y
    oax = 0.0 if far else -c[C_VEL_P] * est[kern.EST_FX + 3]
    oay = 0.0 if far else -c[C_VEL_P] * est[kern.EST_FY + 3]
    return ox, oy, vel_x, vel_y, oax, oay


@inline_kernel
def _velocity_setpoint(c: np.ndarray, est: np.ndarray, ref: np.ndarray, offs: tuple) -> tuple[float, float, float]:
    """Step 1: position P + velocity feed-forward (+ the offsets ``offs``), the speed limited; (m/s, world)."""
    ox, oy, ovx, ovy = offs[0], offs[1], offs[2], offs[3]
    x = est[kern.EST_FX] - c[C_L] * est[kern.EST_ALPHA_Y]  # the vehicle, F = p + l a
    y = est[kern.EST_FY] - c[C_L] * est[kern.EST_ALPHA_X]
    vsx = ref[lay.REF_FX + 1] + ovx + c[C_KP_XY] * (ref[lay.REF_FX] + ox - x)
    vsy = ref[lay.REF_FY + 1] + ovy + c[C_KP_XY] * (ref[lay.REF_FY] + oy - y)
    vsz = ref[lay.REF_Z + 1] + c[C_KP_Z] * (ref[lay.REF_Z] - est[kern.EST_Z])
    sp = math.hypot(vsx, vsy)
    if sp > c[C_VEL_MAX_XY]:
        scale = c[C_VEL_MAX_XY] / sp
        vsx, vsy = vsx * scale, vsy * scale
    vsz = maximum(-c[C_VEL_MAX_Z], minimum(c[C_VEL_MAX_Z], vsz))
    return vsx, vsy, vsz


@inline_kernel
def _acceleration_setpoint(
    c: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray, ref: np.ndarray, offs: tuple
) -> tuple[float, float, float, float, float, float]:
    """Steps 1-2: (ax, ay, az) (m/s^2, world) of the velocity PID with acceleration feed-forward (D on the
    first-order acceleration), and the new velocity integrators (m; stored by the caller)."""
    vsx, vsy, vsz = _velocity_setpoint(c, est, ref, offs)
    l = c[C_L]
    vx, vy = (
        est[kern.EST_FX + 1] - l * est[kern.EST_ALPHA_Y_RATE],
        est[kern.EST_FY + 1] - l * est[kern.EST_ALPHA_X_RATE],
    )
    evx, evy, evz = vsx - vx, vsy - vy, vsz - est[kern.EST_Z_RATE]
    ivx, ivy, ivz = mem[B_IVX] + evx * dt, mem[B_IVY] + evy * dt, mem[B_IVZ] + evz * dt
    phi, theta, psi = est[kern.EST_PHI], est[kern.EST_THETA], est[kern.EST_PSI]
    cps, sps = math.cos(psi), math.sin(psi)
    nx = theta * cps + phi * sps
    ny = theta * sps - phi * cps
    acc_x = c[C_ACC_GAIN] * (c[C_MT] * nx + c[C_MLOAD] * est[kern.EST_ALPHA_Y])
    acc_y = c[C_ACC_GAIN] * (c[C_MT] * ny + c[C_MLOAD] * est[kern.EST_ALPHA_X])
    rfx2, rfy2 = ref[lay.REF_FX + 2], ref[lay.REF_FY + 2]
    ax = rfx2 + offs[4] + c[C_KV_XY] * evx + c[C_KI_XY] * ivx - c[C_KD_XY] * (acc_x - rfx2)
    ay = rfy2 + offs[5] + c[C_KV_XY] * evy + c[C_KI_XY] * ivy - c[C_KD_XY] * (acc_y - rfy2)
    az = ref[lay.REF_Z + 2] + c[C_KV_Z] * evz + c[C_KI_Z] * ivz
    return ax, ay, az, ivx, ivy, ivz


@inline_kernel
def _attitude_setpoint(c: np.ndarray, ax: float, ay: float, az: float, psi_d: float) -> tuple:
    """Step 3: the thrust vector tilt limited as PX4 does -> (thrust N, roll and pitch setpoints rad, tilt
    limited) at the heading ``psi_d`` (rad)."""
    tz = maximum(az + c[C_G], 0.1 * c[C_G])  # never a downward or vanishing thrust
    h = math.hypot(ax, ay)
    h_max = tz * c[C_TAN_TILT]
    tilted = h > h_max
    if tilted:  # keep the vertical part, shrink the horizontal one
        shrink = h_max / h
        ax, ay = ax * shrink, ay * shrink
    thrust = c[C_MT] * math.sqrt(ax * ax + ay * ay + tz * tz)
    cp, sp = math.cos(psi_d), math.sin(psi_d)
    zx, zy = cp * ax + sp * ay, -sp * ax + cp * ay
    norm = math.sqrt(zx * zx + zy * zy + tz * tz)
    phi_d = math.asin(maximum(-1.0, minimum(1.0, -zy / norm)))
    theta_d = math.atan2(zx, tz)
    return thrust, phi_d, theta_d, tilted


@inline_kernel
def _rate_loop(
    c: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray, ref: np.ndarray, att_sp: tuple, u_out: np.ndarray
) -> bool:
    """Step 4: attitude P (setpoint ``att_sp``: roll, pitch, rad) -> rates, rate PI -> torques (N m, body FLU),
    clipped with the thrust ``u_out[0]`` (N) into ``u_out``; the rate integrators kept unless their torque is
    clipped. Returns whether anything was clipped."""
    phi_d, theta_d, thrust = att_sp[0], att_sp[1], u_out[0]
    phi, theta, psi = est[kern.EST_PHI], est[kern.EST_THETA], est[kern.EST_PSI]
    p_sp = c[C_KP_ATT] * (phi_d - phi)
    q_sp = c[C_KP_ATT] * (theta_d - theta)
    r_sp = ref[lay.REF_PSI + 1] + c[C_KP_YAW] * wrap_angle(ref[lay.REF_PSI] - psi)
    r_sp = maximum(-c[C_YAW_RATE_MAX], minimum(c[C_YAW_RATE_MAX], r_sp))
    e_p, e_q = p_sp - est[kern.EST_PHI_RATE], q_sp - est[kern.EST_THETA_RATE]
    i_p, i_q = mem[B_IP] + e_p * dt, mem[B_IQ] + e_q * dt
    tau_phi = c[C_IX] * (c[C_KR_RP] * e_p + c[C_KI_RP] * i_p)
    tau_theta = c[C_IY] * (c[C_KR_RP] * e_q + c[C_KI_RP] * i_q)
    tau_psi = c[C_IZ] * (c[C_KR_YAW] * (r_sp - est[kern.EST_PSI_RATE]) + ref[lay.REF_PSI + 2])
    tp, tt, ts = c[C_TP], c[C_TT], c[C_TS]
    s_p, s_q, s_r = abs(tau_phi) > tp, abs(tau_theta) > tt, abs(tau_psi) > ts
    s_t = thrust > c[C_THRUST_MAX]
    if s_p:
        tau_phi = math.copysign(tp, tau_phi)
    else:
        mem[B_IP] = i_p
    if s_q:
        tau_theta = math.copysign(tt, tau_theta)
    else:
        mem[B_IQ] = i_q
    if s_r:
        tau_psi = math.copysign(ts, tau_psi)
    if s_t:
        thrust = c[C_THRUST_MAX]
    u_out[0], u_out[1], u_out[2], u_out[3] = thrust, tau_phi, tau_theta, tau_psi
    return s_p or s_q or s_r or s_t


@pure_kernel
def cascade_step(
    c: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray, ref: np.ndarray, offs: tuple, u_out: np.ndarray
) -> bool:
    """``CascadeStep.step`` for one run with a finite estimate: ``dt`` (s) since its last step, ``offs`` the
    setpoint offsets (position m, velocity m/s, acceleration m/s^2; x, y each, world; zeros for the stock
    cascade), the command (thrust N, torques N m) into ``u_out``, ``mem`` (``B_*``) updated. Returns
    ``saturated`` (a torque, the thrust or the tilt limit)."""
    ax, ay, az, ivx, ivy, ivz = _acceleration_setpoint(c, mem, dt, est, ref, offs)
    thrust, phi_d, theta_d, tilted = _attitude_setpoint(c, ax, ay, az, ref[lay.REF_PSI])
    u_out[0] = thrust
    sat = _rate_loop(c, mem, dt, est, ref, (phi_d, theta_d), u_out)
    if not tilted:  # anti-windup: the horizontal integrators held while the tilt limit clips
        mem[B_IVX], mem[B_IVY] = ivx, ivy
    if u_out[0] < c[C_THRUST_MAX]:
        mem[B_IVZ] = ivz
    return sat or tilted


# ---- LQR: controllers.lqr.LqrController -----------------------------------------------------------------------------
@inline_kernel
def _rot(cp: float, sp: float, a: float, b: float) -> tuple[float, float]:
    """The world vector (a, b) in the heading-aligned frame (rotation by -psi; ``cp``, ``sp``: cos, sin psi)."""
    return cp * a + sp * b, -sp * a + cp * b


@inline_kernel
def _lqr_errors(c: np.ndarray, est: np.ndarray, ref: np.ndarray, e: np.ndarray, ff: np.ndarray) -> None:
    """The 16 state errors of the linear model in its order (heading-aligned frame, SI and rad) into ``e[:16]``,
    the feed-forward thrust (N) and torques (N m) into ``ff``: the reference state from the flat reference
    (``a* = -F*''/g``, ``p* = F* - l a*``, ``n* = F*^(4)/c - a*``)."""
    l, g, cc, w2 = c[Q_L], c[Q_G], c[Q_C], c[Q_W2]
    ay_r, ay_rd = -ref[lay.REF_FX + 2] / g, -ref[lay.REF_FX + 3] / g
    ax_r, ax_rd = -ref[lay.REF_FY + 2] / g, -ref[lay.REF_FY + 3] / g
    x_r, vx_r = ref[lay.REF_FX] - l * ay_r, ref[lay.REF_FX + 1] - l * ay_rd
    y_r, vy_r = ref[lay.REF_FY] - l * ax_r, ref[lay.REF_FY + 1] - l * ax_rd
    nx_r, nxd_r = ref[lay.REF_FX + 4] / cc - ay_r, ref[lay.REF_FX + 5] / cc - ay_rd
    ny_r, nyd_r = ref[lay.REF_FY + 4] / cc - ax_r, ref[lay.REF_FY + 5] / cc - ax_rd
    nxdd_r = (ref[lay.REF_FX + 6] + w2 * ref[lay.REF_FX + 4]) / cc
    nydd_r = (ref[lay.REF_FY + 6] + w2 * ref[lay.REF_FY + 4]) / cc
    x, y = est[kern.EST_FX] - l * est[kern.EST_ALPHA_Y], est[kern.EST_FY] - l * est[kern.EST_ALPHA_X]
    vx, vy = (
        est[kern.EST_FX + 1] - l * est[kern.EST_ALPHA_Y_RATE],
        est[kern.EST_FY + 1] - l * est[kern.EST_ALPHA_X_RATE],
    )
    psi = est[kern.EST_PSI]
    cp, sp = math.cos(psi), math.sin(psi)
    th_r, mphi_r = _rot(cp, sp, nx_r, ny_r)  # the reference tilt in the heading frame is [theta*, -phi*]
    thd_r, mphid_r = _rot(cp, sp, nxd_r, nyd_r)
    thdd_r, mphidd_r = _rot(cp, sp, nxdd_r, nydd_r)
    e[0], e[1] = _rot(cp, sp, x - x_r, y - y_r)
    e[2] = est[kern.EST_Z] - ref[lay.REF_Z]
    e[3], e[4] = _rot(cp, sp, vx - vx_r, vy - vy_r)
    e[5] = est[kern.EST_Z_RATE] - ref[lay.REF_Z + 1]
    e[6], e[7], e[8] = est[kern.EST_PHI] + mphi_r, est[kern.EST_THETA] - th_r, wrap_angle(psi - ref[lay.REF_PSI])
    e[9], e[10], e[11] = (
        est[kern.EST_PHI_RATE] + mphid_r,
        est[kern.EST_THETA_RATE] - thd_r,
        est[kern.EST_PSI_RATE] - ref[lay.REF_PSI + 1],
    )
    e[12], e[13] = _rot(cp, sp, est[kern.EST_ALPHA_Y] - ay_r, est[kern.EST_ALPHA_X] - ax_r)
    e[14], e[15] = _rot(cp, sp, est[kern.EST_ALPHA_Y_RATE] - ay_rd, est[kern.EST_ALPHA_X_RATE] - ax_rd)
    ff[0], ff[1] = c[Q_MT] * (g + ref[lay.REF_Z + 2]), -c[Q_IX] * mphidd_r
    ff[2], ff[3] = c[Q_IY] * thdd_r, c[Q_IZ] * ref[lay.REF_PSI + 2]


@inline_kernel
def _lqr_motors(c: np.ndarray, mem: np.ndarray, dt: float, ff: np.ndarray, e: np.ndarray) -> None:
    """The delivered thrust and torques the law models (its previous commands through the motors' lag; the
    feed-forward ``ff`` at the first step), stored, and minus ``ff`` into ``e[20:24]``: the four lag states' errors
    (N, N m). Nothing without a lag (the gain has 20 columns then)."""
    lag = c[Q_LAG]
    if not lag > 0.0:
        return
    first = math.isnan(mem[B_DELIVERED])
    a = 1.0 - math.exp(-dt / lag) if dt > 0.0 else 0.0
    for j in range(4):
        d, s = mem[B_DELIVERED + j], mem[B_SENT + j]
        mem[B_DELIVERED + j] = ff[j] if first else d + a * (s - d)
        e[20 + j] = mem[B_DELIVERED + j] - ff[j]


@inline_kernel
def _row_sum(K: np.ndarray, i: int, e: np.ndarray) -> float:
    """``sum(k * e for k, e in zip(K[i], e))`` in Python's order (``0 + k0 e0 + k1 e1 + ...``)."""
    acc = 0.0
    for j in range(K.shape[1]):
        acc = acc + K[i, j] * e[j]
    return acc


@pure_kernel
def lqr_step(
    c: np.ndarray, K: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray, ref: np.ndarray, u_out: np.ndarray
) -> bool:
    """``LqrStep.step`` for one run with a finite estimate: ``u = u* - K e``, the integrals held while anything
    saturates; ``dt`` (s) since its last step, the command (thrust N, torques N m) into ``u_out``, ``mem``
    (``B_*``) updated. Returns ``saturated`` (the thrust or a torque)."""
    e, ff = mem[B_ERROR : B_ERROR + 24], mem[B_FF : B_FF + 4]  # views of the scratch area: nothing allocated
    _lqr_errors(c, est, ref, e, ff)
    e[16] = mem[B_INT] + e[0] * dt  # the integrals of the x, y, z and heading errors
    e[17] = mem[B_INT + 1] + e[1] * dt
    e[18] = mem[B_INT + 2] + e[2] * dt
    e[19] = mem[B_INT + 3] + e[8] * dt
    _lqr_motors(c, mem, dt, ff, e)
    thrust = ff[0] + -_row_sum(K, 0, e)
    tau_phi = ff[1] + -_row_sum(K, 1, e)
    tau_theta = ff[2] + -_row_sum(K, 2, e)
    tau_psi = ff[3] + -_row_sum(K, 3, e)
    tp, tt, ts = c[Q_TP], c[Q_TT], c[Q_TS]
    sat = thrust > c[Q_THRUST_MAX] or thrust < 0.0
    sat = sat or abs(tau_phi) > tp or abs(tau_theta) > tt or abs(tau_psi) > ts
    u_out[0] = minimum(maximum(thrust, 0.0), c[Q_THRUST_MAX])
    u_out[1] = maximum(-tp, minimum(tp, tau_phi))
    u_out[2] = maximum(-tt, minimum(tt, tau_theta))
    u_out[3] = maximum(-ts, minimum(ts, tau_psi))
    for j in range(4):
        if not sat:
            mem[B_INT + j] = e[16 + j]
        mem[B_SENT + j] = u_out[j]
    return sat
