"""The sliding-mode law ``offboard.control.smc.step`` (the sweep's ``smc`` row) for one run, in the order of the
scalar law's expressions (with reciprocals and shared sines: equal to it to about 1e-12,
``tests/test_compiled_laws.py``): its constants (:func:`_smc_constants`, indices ``S_*``), its memory (indices
``M_*``) and :func:`smc_step`. Its switching function is the scalar law's own (``smc.switching``, compiled; see
the package's ``SHARED_SOURCES``). Frames and units as in the scalar law: model frame (world NWU, z up; body FLU),
SI, rad; the estimate and the reference are the vectors of ``estimators.kernels`` and :mod:`.reference_row`. No
screening: a NaN in the estimate flows through its arithmetic, and into its memory.
"""

from __future__ import annotations

import math

import numpy as np

from estimators import kernels as kern
from estimators.kernels import inline_kernel, maximum, minimum, pack_constants, pure_kernel, wrap_angle
from estimators.model import rotations
from estimators.model.flatness import flat_constants
from offboard.control import smc
from offboard.control.compiled import reference_row as lay

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

# ---- a run's memory --------------------------------------------------------------------------------------------------
# smc (smc.step's memory): the error integrals (m s, rad s, m s, m s), the roll / pitch torques commanded at
# the last tick and those modelled as delivered then (N m); then the actuation lag's factor 1 - exp(-dt / lag) and
# the dt (s) it is for (NaN before the first: a control period is the same at every tick, so exp runs once a run)
M_INT_Z, M_INT_PSI, M_INT_FX, M_INT_FY, M_TP_CMD, M_TT_CMD, M_TP_ACT, M_TT_ACT = range(8)
M_LAG_A, M_LAG_DT = 8, 9
SMC_MEMORY = 10


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


# ---- numpy's element-wise functions on scalars -------------------------------------------------------------------
@inline_kernel
def _clip(x: float, lo: float, hi: float) -> float:
    """``np.clip(x, lo, hi)`` (lo <= hi): NaN and a value equal to a bound pass unchanged."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


#: ``smc``'s switching function, compiled from the scalar law itself
_switching = inline_kernel(smc.switching)
#: the thrust direction from the attitude's sines and cosines, compiled from the scalar path's own function
_thrust_direction = inline_kernel(rotations.thrust_direction_trig)


# ---- smc: offboard.control.smc.step ---------------------------------------------------------------------------------
@inline_kernel
def _smc_height(
    c: np.ndarray, dt: float, int_prev: float, est: np.ndarray, ref: np.ndarray, smooth: bool
) -> tuple[float, float]:
    """(the height law's thrust, N, unclipped; the new height-error integral, m s): the full nonlinear ``g_z`` of the
    thrust direction ``n`` (world) and the cable (from the planar swing angles and rates of ``est``)."""
    phi, theta, psi = est[kern.EST_PHI], est[kern.EST_THETA], est[kern.EST_PSI]
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
    n1, n2, n3 = _thrust_direction(sf, cf, st, ct, math.sin(psi), math.cos(psi))
    # tan and cos of each swing angle from one sine / cosine pair (tan = sin / cos: an ulp from libm's tan), and
    # products by 1 / |.| where the scalar law divides by it: the same expressions to an ulp or so
    sy, cy = math.sin(est[kern.EST_ALPHA_Y]), math.cos(est[kern.EST_ALPHA_Y])
    sx, cx = math.sin(est[kern.EST_ALPHA_X]), math.cos(est[kern.EST_ALPHA_X])
    ty, tx = sy / cy, sx / cx
    dty = est[kern.EST_ALPHA_Y_RATE] / (cy * cy)  # numpy's ** 2 is a product
    dtx = est[kern.EST_ALPHA_X_RATE] / (cx * cx)
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
    e_z = est[kern.EST_Z] - ref[lay.REF_Z]
    e_zd = est[kern.EST_Z_RATE] - ref[lay.REF_Z + 1]
    int_z = int_prev + e_z * dt
    s_z = e_zd + c[S_LAMBDA1] * e_z + c[S_LAMBDA0] * int_z
    sw = _switching(s_z, c[S_EPS_Z], smooth)
    thrust = (ref[lay.REF_Z + 2] - f_z - c[S_LAMBDA1] * e_zd - c[S_LAMBDA0] * e_z - c[S_RHO_Z] * sw) / maximum(
        g_z, 1e-3
    )
    return thrust, int_z


@inline_kernel
def _smc_yaw(
    c: np.ndarray, dt: float, int_prev: float, est: np.ndarray, ref: np.ndarray, smooth: bool
) -> tuple[float, float]:
    """(the yaw law's torque, N m, unclipped; the new heading-error integral, rad s)."""
    e_psi = wrap_angle(est[kern.EST_PSI] - ref[lay.REF_PSI])
    e_psid = est[kern.EST_PSI_RATE] - ref[lay.REF_PSI + 1]
    int_psi = int_prev + e_psi * dt
    s_psi = e_psid + c[S_GAMMA1] * e_psi + c[S_GAMMA0] * int_psi
    sw = _switching(s_psi, c[S_EPS_PSI], smooth)
    tau_psi = c[S_IS] * (ref[lay.REF_PSI + 2] - c[S_GAMMA1] * e_psid - c[S_GAMMA0] * e_psi - c[S_RHO_PSI] * sw)
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
    sw = _switching(sigma, c[S_EPS_F], smooth)
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
    vx, int_fx = _smc_axis(c, dt, mem[M_INT_FX], est, ref, kern.EST_FX, lay.REF_FX, smooth)
    vy, int_fy = _smc_axis(c, dt, mem[M_INT_FY], est, ref, kern.EST_FY, lay.REF_FY, smooth)
    # the commanded world tilt acceleration n'' = (v + w2 F^(4)) / c, led by the actuation lag's model
    nddx = (vx + c[S_W2] * est[kern.EST_FX + 4]) * c[S_INV_C]
    nddy = (vy + c[S_W2] * est[kern.EST_FY + 4]) * c[S_INV_C]
    phi, theta, psi = est[kern.EST_PHI], est[kern.EST_THETA], est[kern.EST_PSI]
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
        nddx = nddx + _smc_lead(c, est, ref, kern.EST_FX, lay.REF_FX, cp * a1 + sp * a2)
        nddy = nddy + _smc_lead(c, est, ref, kern.EST_FY, lay.REF_FY, sp * a1 - cp * a2)
    # the heading-aligned tilt t = [theta, -phi]: t'' = Rz(-psi) n'' - 2 w J t' - w' J t + w^2 t
    t1, t2 = theta, -phi
    t1d, t2d = est[kern.EST_THETA_RATE], -est[kern.EST_PHI_RATE]
    w = est[kern.EST_PSI_RATE]
    wd = ref[lay.REF_PSI + 2]
    t1dd = cp * nddx + sp * nddy + 2.0 * w * t2d + wd * t2 + w * w * t1
    t2dd = -sp * nddx + cp * nddy - 2.0 * w * t1d - wd * t1 + w * w * t2
    tau_theta = c[S_IT] * t1dd
    tau_phi = -c[S_IP] * t2dd
    u_out[0], u_out[1], u_out[2], u_out[3] = thrust, tau_phi, tau_theta, tau_psi
    return _smc_saturate(c, mem, (int_z, int_psi, int_fx, int_fy), (tp_act, tt_act), u_out)
