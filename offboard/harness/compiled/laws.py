"""The controllers of a compiled run, one run at a time: the sliding-mode law ``offboard.control.smc.step`` (the
``smc`` row), the stock cascade (``cascade``, and ``zv`` / ``zvd`` behind a reference shaped beforehand by the
driver), the swing-feedback cascade (``swing-feedback``) and LQR with its motor-lag states (``lqr``), in the
order of the scalar laws' expressions (``offboard.control.smc``, ``offboard.control.controllers``).

Over 500 lines because it is the driver's one entry to the controllers: :func:`law_step` dispatches one tick to
four laws that share the constants' and memories' layouts (the index constants the driver and the tests use), the
baselines' screening and the scalar mirrors of numpy's element-wise functions; each law is 100-150 lines of it.

A law is a code (``LAW_*``), a float64 constants vector ``c`` (its indices named by the ``S_*`` (smc), ``C_*``
(cascade, swing-feedback) and ``Q_*`` (LQR) constants), the LQR gain ``K`` (empty for the others), all from
:func:`law_constants`, and a run's memory (:func:`law_memory`, indices ``M_*`` / ``B_*``): :func:`law_step` is
one control tick of one run. Frames and units as in the scalar path: model frame (world NWU, z up; body FLU), SI,
rad; the estimate and the reference are the vectors of :mod:`.layout`.

As the scalar laws: the baselines screen the estimate (a run whose estimate is not finite gets the nominal hover
command and keeps its memory; each baseline's ``dt`` from its own last step time); ``smc`` does not screen (its
``dt`` is the caller's; a NaN flows through its arithmetic, and into its memory). Numpy's
``maximum`` / ``minimum`` (NaN propagates; between equal values the second argument) and ``clip`` (a value equal
to a bound, or NaN, passes unchanged) are mirrored by ``layout.maximum``, ``layout.minimum`` and :func:`_clip`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.harness.compiled.layout import (
    EST_ALPHA_X,
    EST_ALPHA_X_RATE,
    EST_ALPHA_Y,
    EST_ALPHA_Y_RATE,
    EST_FX,
    EST_FY,
    EST_PHI,
    EST_PHI_RATE,
    EST_PSI,
    EST_PSI_RATE,
    EST_SIZE,
    EST_THETA,
    EST_THETA_RATE,
    EST_Z,
    EST_Z_RATE,
    REF_FX,
    REF_FY,
    REF_PSI,
    REF_Z,
    inline_kernel,
    maximum,
    minimum,
    pack_constants,
    pure_kernel,
    wrap_angle,
)

LAW_SMC, LAW_CASCADE, LAW_SWING_FEEDBACK, LAW_LQR = 0, 1, 2, 3
#: the sweep's rows these laws fly (the registry's controllers of these names; ``zv`` / ``zvd``: the cascade behind
#: the reference shaper)
TORQUE_LAWS = ("smc", "cascade", "zv", "zvd", "swing-feedback", "lqr")

# ---- smc's constants (smc.ControllerParams of the nominal vehicle) ---------------------------------------------------
# flat constants (m, m/s^2, m/s^4 per rad, 1/s^2), masses (kg), inertia (kg m^2), cos of the largest tilt
S_L, S_G, S_C, S_W2, S_M, S_MLOAD, S_MT, S_IP, S_IT, S_IS, S_COS_MAX = range(11)
# gains (smc.Gains): height, yaw, the horizontal K0..K5 (S_K + i), the switching amplitudes
S_LAMBDA0, S_LAMBDA1, S_GAMMA0, S_GAMMA1, S_K = 11, 12, 13, 14, 15
S_RHO_Z, S_RHO_PSI, S_RHO_F = 21, 22, 23
# smooth switching (1.0) or sign (0.0) and its widths (ControllerParams.layers), the actuation lag (s)
S_SMOOTH, S_EPS_Z, S_EPS_PSI, S_EPS_F, S_LAG = 24, 25, 26, 27, 28
# limits (N, N m); shared roll / pitch margin (1.0 or 0.0), a motor's largest thrust and margin at hover (N)
S_THRUST_MIN, S_THRUST_MAX, S_TP_MAX, S_TT_MAX, S_TS_MAX, S_SHARED, S_F_MAX, S_DF_HOVER = range(29, 37)
# reciprocals the law multiplies by where the scalar law divides (1/c, 1/I_theta, 1/I_phi, 1/(M Mt); an ulp apart)
S_INV_C, S_INV_IT, S_INV_IP, S_INV_M_MT = range(37, 41)
SMC_SIZE = 41

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
# smc (smc.step's memory): the error integrals (m s, rad s, m s, m s), the roll / pitch torques commanded at
# the last tick and those modelled as delivered then (N m); then the actuation lag's factor 1 - exp(-dt / lag) and
# the dt (s) it is for (NaN before the first: a control period is the same at every tick, so exp runs once a run)
M_INT_Z, M_INT_PSI, M_INT_FX, M_INT_FY, M_TP_CMD, M_TT_CMD, M_TP_ACT, M_TT_ACT = range(8)
M_LAG_A, M_LAG_DT = 8, 9
SMC_MEMORY = 10
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

_SIZES = {LAW_SMC: SMC_SIZE, LAW_CASCADE: CASCADE_SIZE, LAW_SWING_FEEDBACK: SWING_SIZE, LAW_LQR: LQR_SIZE}


# ---- Python side: the constants and the initial memory ------------------------------------------------------------
def _smc_constants(params: smc.ControllerParams) -> np.ndarray:
    """``smc.step``'s constants for ``params`` (the nominal vehicle's law)."""
    v = params.vehicle
    k = flat_constants(v)
    G = params.gains
    eps_z, eps_psi, eps_f = params.layers()
    Ip, It, Is = v.inertia
    tp, tt, ts = params.torque_max
    f_max, df_hover = smc._hover_margin(params)  # the figures smc.shared_thrust_range works from
    values = {S_L: k.l, S_G: k.g, S_C: k.c, S_W2: k.omega2, S_M: v.mass_vehicle, S_MLOAD: v.mass_load}
    values.update({S_MT: v.total_mass, S_IP: Ip, S_IT: It, S_IS: Is, S_COS_MAX: math.cos(params.max_tilt)})
    values.update({S_LAMBDA0: G.lambda0, S_LAMBDA1: G.lambda1, S_GAMMA0: G.gamma0, S_GAMMA1: G.gamma1})
    values.update({S_K + i: G.K[i] for i in range(6)})
    values.update({S_RHO_Z: G.rho_z, S_RHO_PSI: G.rho_psi, S_RHO_F: G.rho_F})
    values.update({S_SMOOTH: params.switching == "smooth", S_EPS_Z: eps_z, S_EPS_PSI: eps_psi, S_EPS_F: eps_f})
    values.update({S_LAG: params.actuation_lag_s, S_THRUST_MIN: params.thrust_min, S_THRUST_MAX: params.thrust_max})
    values.update({S_TP_MAX: tp, S_TT_MAX: tt, S_TS_MAX: ts, S_SHARED: params.shared_roll_pitch})
    values.update({S_F_MAX: f_max, S_DF_HOVER: df_hover})
    values.update({S_INV_C: 1.0 / k.c, S_INV_IT: 1.0 / It, S_INV_IP: 1.0 / Ip})
    values.update({S_INV_M_MT: 1.0 / (v.mass_vehicle * v.total_mass)})
    return pack_constants(SMC_SIZE, values)


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


def law_constants(law: str, vehicle: Vehicle, params: smc.ControllerParams) -> tuple[int, np.ndarray, np.ndarray]:
    """(code, constants ``c``, LQR gain ``K``: 4 x 20 or 4 x 24, empty (0, 0) for the other laws) of a row of
    :data:`TORQUE_LAWS` flown by the nominal ``vehicle``; ``params``: ``smc``'s law (``registry.smc_params(nominal)``,
    as the sweep passes it). The baselines' figures come from the registry's own controllers (gains, the applet's
    constants, LQR's gain), so the paths cannot drift apart; ``zv`` / ``zvd`` are the cascade (their shaped
    reference is the driver's)."""
    from offboard.control.controllers import registry
    from offboard.control.controllers.lqr import LqrController
    from offboard.control.controllers.shaping import ShapedCascade

    if law not in TORQUE_LAWS:
        raise ValueError(f"the compiled laws are {', '.join(TORQUE_LAWS)}, not {law!r}")
    no_gain = np.zeros((0, 0))
    if law == "smc":
        return LAW_SMC, _smc_constants(params), no_gain
    scalar = registry.make(law, vehicle)
    if isinstance(scalar, LqrController):
        return LAW_LQR, _lqr_constants(scalar), np.array(scalar.K, dtype=np.float64)
    if isinstance(scalar, ShapedCascade):
        scalar = scalar.cascade
    from offboard.control.controllers.swing_feedback import SwingFeedbackCascade

    code = LAW_SWING_FEEDBACK if isinstance(scalar, SwingFeedbackCascade) else LAW_CASCADE
    return code, _cascade_constants(scalar, vehicle), no_gain


def law_memory(code: int, c: np.ndarray) -> np.ndarray:
    """A run's memory before its first tick for the law ``code`` with constants ``c`` (checked against the code):
    smc's 8 zeros (and its lag factor's cache, empty); the baselines' integrators at zero, their last step time
    NaN (and LQR's delivered thrust and torques NaN: set to the feed-forward at the first step)."""
    if code not in _SIZES or c.shape != (_SIZES[code],):
        raise ValueError(f"law code {code} with {c.shape} constants: not a pair law_constants gives")
    if code == LAW_SMC:
        mem = np.zeros(SMC_MEMORY)
        mem[M_LAG_DT] = math.nan
        return mem
    size = {LAW_CASCADE: CASCADE_MEMORY, LAW_SWING_FEEDBACK: SWING_MEMORY, LAW_LQR: LQR_MEMORY}[code]
    mem = np.zeros(size)
    mem[B_T_LAST] = math.nan
    if code == LAW_LQR:
        mem[B_DELIVERED : B_DELIVERED + 4] = math.nan
    return mem


# ---- numpy's element-wise functions on scalars -------------------------------------------------------------------
@inline_kernel
def _clip(x: float, lo: float, hi: float) -> float:
    """``np.clip(x, lo, hi)`` (lo <= hi): NaN and a value equal to a bound pass unchanged."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@inline_kernel
def _switch(s: float, smooth: bool, eps: float) -> float:
    """``smc``'s switching function: ``s / (|s| + eps)`` when ``smooth``, else ``np.sign(s)`` (+0 at +-0, NaN at
    NaN)."""
    if smooth:
        return s / (abs(s) + eps)
    if s > 0.0:
        return 1.0
    if s < 0.0:
        return -1.0
    if s == 0.0:
        return 0.0
    return s


@inline_kernel
def estimate_is_finite(est: np.ndarray) -> bool:
    """The baselines' screen (``BatchedBaseline``) and the attitude-level law's (``ControlState.is_finite``): the sum
    of the two flat chains and the named scalars, summed as numpy and Python sum them (an overflowing sum is refused
    too), is finite."""
    sx = est[EST_FX]
    sy = est[EST_FY]
    for i in range(1, 6):
        sx = sx + est[EST_FX + i]
        sy = sy + est[EST_FY + i]
    rest = 0.0
    for i in range(EST_Z, EST_SIZE):
        rest = rest + est[i]
    return math.isfinite(sx + sy + rest)


# ---- smc: offboard.control.smc.step ---------------------------------------------------------------------------------
@inline_kernel
def _smc_height(
    c: np.ndarray, dt: float, int_prev: float, est: np.ndarray, ref: np.ndarray, smooth: bool
) -> tuple[float, float]:
    """(the height law's thrust, N, unclipped; the new height-error integral, m s): the full nonlinear ``g_z`` of the
    thrust direction ``n`` (world) and the cable (from the planar swing angles and rates of ``est``)."""
    phi, theta, psi = est[EST_PHI], est[EST_THETA], est[EST_PSI]
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    n1 = sf * sp + cf * cp * st
    n2 = cf * sp * st - cp * sf
    n3 = cf * ct
    # tan and cos of each swing angle from one sine / cosine pair (tan = sin / cos: an ulp from libm's tan), and
    # products by 1 / |.| where the scalar law divides by it: the same expressions to an ulp or so
    sy, cy = math.sin(est[EST_ALPHA_Y]), math.cos(est[EST_ALPHA_Y])
    sx, cx = math.sin(est[EST_ALPHA_X]), math.cos(est[EST_ALPHA_X])
    ty, tx = sy / cy, sx / cx
    dty = est[EST_ALPHA_Y_RATE] / (cy * cy)  # numpy's ** 2 is a product
    dtx = est[EST_ALPHA_X_RATE] / (cx * cx)
    nn = math.sqrt(1.0 + ty * ty + tx * tx)
    inv_n = 1.0 / nn
    inv_n2 = inv_n * inv_n
    r1, r2, r3 = ty * inv_n, tx * inv_n, -inv_n
    dn = (ty * dty + tx * dtx) * inv_n
    d1, d2, d3 = (dty * nn - ty * dn) * inv_n2, (dtx * nn - tx * dn) * inv_n2, dn * inv_n2
    nr = n1 * r1 + n2 * r2 + n3 * r3
    m, Mt = c[S_MLOAD], c[S_MT]
    g_z = (Mt * maximum(n3, c[S_COS_MAX]) - m * nr * r3) * c[S_INV_M_MT]
    f_z = m * c[S_L] * (d1 * d1 + d2 * d2 + d3 * d3) * r3 / Mt - c[S_G]
    e_z = est[EST_Z] - ref[REF_Z]
    e_zd = est[EST_Z_RATE] - ref[REF_Z + 1]
    int_z = int_prev + e_z * dt
    s_z = e_zd + c[S_LAMBDA1] * e_z + c[S_LAMBDA0] * int_z
    sw = _switch(s_z, smooth, c[S_EPS_Z])
    thrust = (ref[REF_Z + 2] - f_z - c[S_LAMBDA1] * e_zd - c[S_LAMBDA0] * e_z - c[S_RHO_Z] * sw) / maximum(g_z, 1e-3)
    return thrust, int_z


@inline_kernel
def _smc_yaw(
    c: np.ndarray, dt: float, int_prev: float, est: np.ndarray, ref: np.ndarray, smooth: bool
) -> tuple[float, float]:
    """(the yaw law's torque, N m, unclipped; the new heading-error integral, rad s)."""
    e_psi = wrap_angle(est[EST_PSI] - ref[REF_PSI])
    e_psid = est[EST_PSI_RATE] - ref[REF_PSI + 1]
    int_psi = int_prev + e_psi * dt
    s_psi = e_psid + c[S_GAMMA1] * e_psi + c[S_GAMMA0] * int_psi
    sw = _switch(s_psi, smooth, c[S_EPS_PSI])
    tau_psi = c[S_IS] * (ref[REF_PSI + 2] - c[S_GAMMA1] * e_psid - c[S_GAMMA0] * e_psi - c[S_RHO_PSI] * sw)
    return tau_psi, int_psi


@inline_kernel
def _smc_axis(
    c: np.ndarray, dt: float, int_prev: float, est: np.ndarray, ref: np.ndarray, ie: int, ir: int, smooth: bool
) -> tuple[float, float]:
    """(the commanded ``F^(6)`` of one world axis, m/s^6; the new integral of its ``F`` error, m s): the flat chain
    ``est[ie:ie + 6]`` against the reference's orders ``ref[ir:ir + 7]``."""
    K0, K1, K2, K3, K4, K5 = c[S_K], c[S_K + 1], c[S_K + 2], c[S_K + 3], c[S_K + 4], c[S_K + 5]
    e0, e1, e2 = est[ie] - ref[ir], est[ie + 1] - ref[ir + 1], est[ie + 2] - ref[ir + 2]
    e3, e4, e5 = est[ie + 3] - ref[ir + 3], est[ie + 4] - ref[ir + 4], est[ie + 5] - ref[ir + 5]
    int_f = int_prev + e0 * dt
    sigma = e5 + K5 * e4 + K4 * e3 + K3 * e2 + K2 * e1 + K1 * e0 + K0 * int_f
    sw = _switch(sigma, smooth, c[S_EPS_F])
    v = ref[ir + 6] - K5 * e5 - K4 * e4 - K3 * e3 - K2 * e2 - K1 * e1 - K0 * e0 - c[S_RHO_F] * sw
    return v, int_f


@inline_kernel
def _smc_lead(c: np.ndarray, est: np.ndarray, ref: np.ndarray, ie: int, ir: int, tilt_acc: float) -> float:
    """The actuation lag's lead on one world axis's tilt acceleration (rad/s^2): ``lag n^(3)`` from the ``F^(6)``
    the modelled delivered tilt acceleration ``tilt_acc`` (rad/s^2, world) gives."""
    K0, K1, K2, K3, K4, K5 = c[S_K], c[S_K + 1], c[S_K + 2], c[S_K + 3], c[S_K + 4], c[S_K + 5]
    e1, e2, e3 = est[ie + 1] - ref[ir + 1], est[ie + 2] - ref[ir + 2], est[ie + 3] - ref[ir + 3]
    e4, e5 = est[ie + 4] - ref[ir + 4], est[ie + 5] - ref[ir + 5]
    e6 = c[S_C] * tilt_acc - c[S_W2] * est[ie + 4] - ref[ir + 6]
    dv = -K5 * e6 - K4 * e5 - K3 * e4 - K2 * e3 - K1 * e2 - K0 * e1
    return c[S_LAG] * (dv + c[S_W2] * est[ie + 5]) * c[S_INV_C]


@inline_kernel
def _smc_saturate(c: np.ndarray, mem: np.ndarray, ints: tuple, acts: tuple, u_out: np.ndarray) -> bool:
    """Clip the command ``u_out`` in place (the shared roll / pitch margin too when ``S_SHARED``), keep each loop's
    integral unless its command was clipped (``ints``: z, psi, F_x, F_y), remember the clipped roll / pitch
    torques and the modelled delivered ones (``acts``); returns ``saturated``."""
    thrust, tau_phi, tau_theta, tau_psi = u_out[0], u_out[1], u_out[2], u_out[3]
    lo, hi = c[S_THRUST_MIN], c[S_THRUST_MAX]
    tp_max, tt_max, ts_max = c[S_TP_MAX], c[S_TT_MAX], c[S_TS_MAX]
    s1 = thrust < lo or thrust > hi
    s2 = abs(tau_phi) > tp_max
    s3 = abs(tau_theta) > tt_max
    s4 = abs(tau_psi) > ts_max
    tau_phi, tau_theta = _clip(tau_phi, -tp_max, tp_max), _clip(tau_theta, -tt_max, tt_max)
    thrust = _clip(thrust, lo, hi)
    if c[S_SHARED] != 0.0:  # the pair scaled into the motors' shared margin, the thrust left the margin it needs
        share = abs(tau_phi) / tp_max + abs(tau_theta) / tt_max
        over = share > 1.0
        scale = share if over else 1.0
        tau_phi, tau_theta, share = tau_phi / scale, tau_theta / scale, share / scale
        s2 = s2 or over
        need = share * c[S_DF_HOVER]  # smc.shared_thrust_range
        t_lo, t_hi = 4.0 * need, 4.0 * (c[S_F_MAX] - need)
        s1 = s1 or thrust < t_lo or thrust > t_hi
        thrust = minimum(maximum(thrust, t_lo), t_hi)
    u_out[0], u_out[1], u_out[2], u_out[3] = thrust, tau_phi, tau_theta, _clip(tau_psi, -ts_max, ts_max)
    if not s1:
        mem[M_INT_Z] = ints[0]
    if not s4:
        mem[M_INT_PSI] = ints[1]
    if not (s2 or s3):  # both horizontal integrals share the roll and pitch torques
        mem[M_INT_FX], mem[M_INT_FY] = ints[2], ints[3]
    mem[M_TP_CMD], mem[M_TT_CMD], mem[M_TP_ACT], mem[M_TT_ACT] = u_out[1], u_out[2], acts[0], acts[1]
    return s1 or s2 or s3 or s4


@pure_kernel
def smc_step(c: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray, ref: np.ndarray, u_out: np.ndarray) -> bool:
    """``offboard.control.smc.step`` for one run: ``dt`` (s) since the previous tick (0 at the first), the
    command (thrust N, tau_phi, tau_theta, tau_psi N m, body FLU) into ``u_out``, ``mem`` (``M_*``) updated;
    returns ``saturated``. No screening: a NaN in ``est`` gives NaN commands."""
    smooth = c[S_SMOOTH] != 0.0
    thrust, int_z = _smc_height(c, dt, mem[M_INT_Z], est, ref, smooth)
    tau_psi, int_psi = _smc_yaw(c, dt, mem[M_INT_PSI], est, ref, smooth)
    vx, int_fx = _smc_axis(c, dt, mem[M_INT_FX], est, ref, EST_FX, REF_FX, smooth)
    vy, int_fy = _smc_axis(c, dt, mem[M_INT_FY], est, ref, EST_FY, REF_FY, smooth)
    # the commanded world tilt acceleration n'' = (v + w2 F^(4)) / c, led by the actuation lag's model
    nddx = (vx + c[S_W2] * est[EST_FX + 4]) * c[S_INV_C]
    nddy = (vy + c[S_W2] * est[EST_FY + 4]) * c[S_INV_C]
    phi, theta, psi = est[EST_PHI], est[EST_THETA], est[EST_PSI]
    sp, cp = math.sin(psi), math.cos(psi)
    lag = c[S_LAG]
    tp_act = tt_act = 0.0
    if lag > 0.0:
        if dt != mem[M_LAG_DT]:
            mem[M_LAG_A], mem[M_LAG_DT] = (1.0 - math.exp(-dt / lag) if dt > 0.0 else 0.0), dt
        a = mem[M_LAG_A]
        tp_act = mem[M_TP_ACT] + a * (mem[M_TP_CMD] - mem[M_TP_ACT])
        tt_act = mem[M_TT_ACT] + a * (mem[M_TT_CMD] - mem[M_TT_ACT])
        a1, a2 = tt_act * c[S_INV_IT], tp_act * c[S_INV_IP]  # delivered [theta'', -phi''] = (a1, -a2)
        nddx = nddx + _smc_lead(c, est, ref, EST_FX, REF_FX, cp * a1 + sp * a2)
        nddy = nddy + _smc_lead(c, est, ref, EST_FY, REF_FY, sp * a1 - cp * a2)
    # the heading-aligned tilt t = [theta, -phi]: t'' = Rz(-psi) n'' - 2 w J t' - w' J t + w^2 t
    t1, t2 = theta, -phi
    t1d, t2d = est[EST_THETA_RATE], -est[EST_PHI_RATE]
    w = est[EST_PSI_RATE]
    wd = ref[REF_PSI + 2]
    t1dd = cp * nddx + sp * nddy + 2.0 * w * t2d + wd * t2 + w * w * t1
    t2dd = -sp * nddx + cp * nddy - 2.0 * w * t1d - wd * t1 + w * w * t2
    tau_theta = c[S_IT] * t1dd
    tau_phi = -c[S_IP] * t2dd
    u_out[0], u_out[1], u_out[2], u_out[3] = thrust, tau_phi, tau_theta, tau_psi
    return _smc_saturate(c, mem, (int_z, int_psi, int_fx, int_fy), (tp_act, tt_act), u_out)


# ---- the cascade: controllers.cascade.CascadeController (and SwingFeedbackCascade's offsets) ----------------------
@pure_kernel
def swing_offsets(c: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray) -> tuple[float, ...]:
    """``SwingFeedbackStep.offsets``: the applet's position (m), velocity (m/s) and acceleration (m/s^2) setpoint
    offsets, world (x, y each), its memory (``B_REST_*``, ``B_OFF_*``, ``B_VEL_*``) advanced by ``dt`` (s)."""
    dx, dy = c[C_L] * est[EST_ALPHA_Y], c[C_L] * est[EST_ALPHA_X]  # payload - vehicle, horizontal (m, world)
    alpha = dt / (dt + c[C_REST_RC])
    rest_x = mem[B_REST_X] + alpha * (dx - mem[B_REST_X])
    rest_y = mem[B_REST_Y] + alpha * (dy - mem[B_REST_Y])
    ox, oy = mem[B_OFF_X] + mem[B_VEL_X] * dt, mem[B_OFF_Y] + mem[B_VEL_Y] * dt
    far = math.hypot(dx, dy) > c[C_DIST_MAX]  # beyond SLUP_DIST_MAX the offsets stop growing
    vel_x = 0.0 if far else c[C_WP_POS_P] * (-ox - rest_x)
    vel_y = 0.0 if far else c[C_WP_POS_P] * (-oy - rest_y)
    mem[B_REST_X], mem[B_REST_Y], mem[B_OFF_X], mem[B_OFF_Y] = rest_x, rest_y, ox, oy
    mem[B_VEL_X], mem[B_VEL_Y] = vel_x, vel_y
    oax = 0.0 if far else -c[C_VEL_P] * est[EST_FX + 3]
    oay = 0.0 if far else -c[C_VEL_P] * est[EST_FY + 3]
    return ox, oy, vel_x, vel_y, oax, oay


@inline_kernel
def _velocity_setpoint(c: np.ndarray, est: np.ndarray, ref: np.ndarray, offs: tuple) -> tuple[float, float, float]:
    """Step 1: position P + velocity feed-forward (+ the offsets ``offs``), the speed limited; (m/s, world)."""
    ox, oy, ovx, ovy = offs[0], offs[1], offs[2], offs[3]
    x = est[EST_FX] - c[C_L] * est[EST_ALPHA_Y]  # the vehicle, F = p + l a
    y = est[EST_FY] - c[C_L] * est[EST_ALPHA_X]
    vsx = ref[REF_FX + 1] + ovx + c[C_KP_XY] * (ref[REF_FX] + ox - x)
    vsy = ref[REF_FY + 1] + ovy + c[C_KP_XY] * (ref[REF_FY] + oy - y)
    vsz = ref[REF_Z + 1] + c[C_KP_Z] * (ref[REF_Z] - est[EST_Z])
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
    vx, vy = est[EST_FX + 1] - l * est[EST_ALPHA_Y_RATE], est[EST_FY + 1] - l * est[EST_ALPHA_X_RATE]
    evx, evy, evz = vsx - vx, vsy - vy, vsz - est[EST_Z_RATE]
    ivx, ivy, ivz = mem[B_IVX] + evx * dt, mem[B_IVY] + evy * dt, mem[B_IVZ] + evz * dt
    phi, theta, psi = est[EST_PHI], est[EST_THETA], est[EST_PSI]
    cps, sps = math.cos(psi), math.sin(psi)
    nx = theta * cps + phi * sps
    ny = theta * sps - phi * cps
    acc_x = c[C_ACC_GAIN] * (c[C_MT] * nx + c[C_MLOAD] * est[EST_ALPHA_Y])
    acc_y = c[C_ACC_GAIN] * (c[C_MT] * ny + c[C_MLOAD] * est[EST_ALPHA_X])
    rfx2, rfy2 = ref[REF_FX + 2], ref[REF_FY + 2]
    ax = rfx2 + offs[4] + c[C_KV_XY] * evx + c[C_KI_XY] * ivx - c[C_KD_XY] * (acc_x - rfx2)
    ay = rfy2 + offs[5] + c[C_KV_XY] * evy + c[C_KI_XY] * ivy - c[C_KD_XY] * (acc_y - rfy2)
    az = ref[REF_Z + 2] + c[C_KV_Z] * evz + c[C_KI_Z] * ivz
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
    phi, theta, psi = est[EST_PHI], est[EST_THETA], est[EST_PSI]
    p_sp = c[C_KP_ATT] * (phi_d - phi)
    q_sp = c[C_KP_ATT] * (theta_d - theta)
    r_sp = ref[REF_PSI + 1] + c[C_KP_YAW] * wrap_angle(ref[REF_PSI] - psi)
    r_sp = maximum(-c[C_YAW_RATE_MAX], minimum(c[C_YAW_RATE_MAX], r_sp))
    e_p, e_q = p_sp - est[EST_PHI_RATE], q_sp - est[EST_THETA_RATE]
    i_p, i_q = mem[B_IP] + e_p * dt, mem[B_IQ] + e_q * dt
    tau_phi = c[C_IX] * (c[C_KR_RP] * e_p + c[C_KI_RP] * i_p)
    tau_theta = c[C_IY] * (c[C_KR_RP] * e_q + c[C_KI_RP] * i_q)
    tau_psi = c[C_IZ] * (c[C_KR_YAW] * (r_sp - est[EST_PSI_RATE]) + ref[REF_PSI + 2])
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
    thrust, phi_d, theta_d, tilted = _attitude_setpoint(c, ax, ay, az, ref[REF_PSI])
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
    ay_r, ay_rd = -ref[REF_FX + 2] / g, -ref[REF_FX + 3] / g
    ax_r, ax_rd = -ref[REF_FY + 2] / g, -ref[REF_FY + 3] / g
    x_r, vx_r = ref[REF_FX] - l * ay_r, ref[REF_FX + 1] - l * ay_rd
    y_r, vy_r = ref[REF_FY] - l * ax_r, ref[REF_FY + 1] - l * ax_rd
    nx_r, nxd_r = ref[REF_FX + 4] / cc - ay_r, ref[REF_FX + 5] / cc - ay_rd
    ny_r, nyd_r = ref[REF_FY + 4] / cc - ax_r, ref[REF_FY + 5] / cc - ax_rd
    nxdd_r = (ref[REF_FX + 6] + w2 * ref[REF_FX + 4]) / cc
    nydd_r = (ref[REF_FY + 6] + w2 * ref[REF_FY + 4]) / cc
    x, y = est[EST_FX] - l * est[EST_ALPHA_Y], est[EST_FY] - l * est[EST_ALPHA_X]
    vx, vy = est[EST_FX + 1] - l * est[EST_ALPHA_Y_RATE], est[EST_FY + 1] - l * est[EST_ALPHA_X_RATE]
    psi = est[EST_PSI]
    cp, sp = math.cos(psi), math.sin(psi)
    th_r, mphi_r = _rot(cp, sp, nx_r, ny_r)  # the reference tilt in the heading frame is [theta*, -phi*]
    thd_r, mphid_r = _rot(cp, sp, nxd_r, nyd_r)
    thdd_r, mphidd_r = _rot(cp, sp, nxdd_r, nydd_r)
    e[0], e[1] = _rot(cp, sp, x - x_r, y - y_r)
    e[2] = est[EST_Z] - ref[REF_Z]
    e[3], e[4] = _rot(cp, sp, vx - vx_r, vy - vy_r)
    e[5] = est[EST_Z_RATE] - ref[REF_Z + 1]
    e[6], e[7], e[8] = est[EST_PHI] + mphi_r, est[EST_THETA] - th_r, wrap_angle(psi - ref[REF_PSI])
    e[9], e[10], e[11] = est[EST_PHI_RATE] + mphid_r, est[EST_THETA_RATE] - thd_r, est[EST_PSI_RATE] - ref[REF_PSI + 1]
    e[12], e[13] = _rot(cp, sp, est[EST_ALPHA_Y] - ay_r, est[EST_ALPHA_X] - ax_r)
    e[14], e[15] = _rot(cp, sp, est[EST_ALPHA_Y_RATE] - ay_rd, est[EST_ALPHA_X_RATE] - ax_rd)
    ff[0], ff[1] = c[Q_MT] * (g + ref[REF_Z + 2]), -c[Q_IX] * mphidd_r
    ff[2], ff[3] = c[Q_IY] * thdd_r, c[Q_IZ] * ref[REF_PSI + 2]


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


# ---- one tick --------------------------------------------------------------------------------------------------------
@pure_kernel
def law_step(
    code: int,
    c: np.ndarray,
    K: np.ndarray,
    mem: np.ndarray,
    t: float,
    dt: float,
    est: np.ndarray,
    ref: np.ndarray,
    u_out: np.ndarray,
) -> bool:
    """One control tick of one run: ``t`` (s); ``dt`` (s) since the previous tick (0 at the first; ``smc``'s,
    the baselines use their own last step time); ``est`` the estimate (``EST_*``), ``ref`` the reference row
    (``REF_*``); the command (thrust N, tau_phi, tau_theta, tau_psi N m, body FLU) into ``u_out`` (4,), ``mem``
    updated in place. Returns ``saturated``."""
    if code == LAW_SMC:
        return smc_step(c, mem, dt, est, ref, u_out)
    if not estimate_is_finite(est):  # the baselines: hover, memory kept
        u_out[0], u_out[1], u_out[2], u_out[3] = c[BASE_HOVER], 0.0, 0.0, 0.0
        return False
    t_last = mem[B_T_LAST]
    own_dt = 0.0 if math.isnan(t_last) else maximum(0.0, t - t_last)
    mem[B_T_LAST] = t
    if code == LAW_LQR:
        return lqr_step(c, K, mem, own_dt, est, ref, u_out)
    if code == LAW_SWING_FEEDBACK:
        offs = swing_offsets(c, mem, own_dt, est)
    elif code == LAW_CASCADE:
        offs = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    else:
        raise ValueError("unknown law code")
    return cascade_step(c, mem, own_dt, est, ref, offs, u_out)
