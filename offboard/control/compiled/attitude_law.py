"""The attitude-level sliding-mode law of a compiled run (the ``smc-attitude`` row):
``offboard.control.smc_attitude.step`` for one run, the scalar law's expressions in its order.

The law commands a thrust and an attitude setpoint, which PX4's attitude loops (``sim_bridge.inner.compiled``)
turn into the motors' wrench; it also reports the torques it expects the autopilot's rate loop to apply, which the
driver gives the filter (``push_command``) as the scalar path does. A law is its constants ``c``
(:func:`attitude_constants`, indices ``A_*``), a run's memory (:func:`attitude_memory`, indices ``AM_*``:
``smc.ControllerMemory``'s fields and a scratch area) and the command it writes (``CMD_*``: 7 floats). Frames and
units as in the scalar law: model frame (world NWU, z up; body FLU), SI, rad; the estimate and the reference are the
vectors of ``estimators.kernels`` and :mod:`.reference_row`.

Mirrored to the last bit (``tests/test_compiled_attitude.py``): Python's ``min`` / ``max`` and ``math.hypot``
(``kernels.py_min``, ``py_max``, ``py_hypot``), ``float ** 2`` (libm's ``pow``, which differs from ``x * x`` in the
last bit for about one argument in a thousand: the exponent is read from the constants so that LLVM cannot turn the
call into a product) and the screens: a non-finite estimate or reference gives the level hover command and keeps
the memory, as does a non-finite result.
"""

from __future__ import annotations

import math

import numpy as np

from estimators import kernels as kern
from estimators.kernels import inline_kernel, pack_constants, pure_kernel, py_hypot, py_max, py_min, wrap_angle
from offboard.control import smc
from offboard.control.compiled import reference_row as lay
from offboard.control.compiled.laws import estimate_is_finite
from offboard.control.smc_attitude import AttitudeParams

#: the law's code beside ``laws.LAW_*`` (the driver dispatches it itself: it writes a 7-float command)
LAW_SMC_ATTITUDE = 4

# ---- constants (smc_attitude.AttitudeParams of the nominal vehicle, and the law's derived figures) ----------------
# with a load (1.0 / 0.0); r, the relative degree of the horizontal surface (5 with a load, 3 without); its
# coefficients k0 .. k_{r-1} (A_K + i)
A_WITH_LOAD, A_R, A_K = 0, 1, 2
# c (m/s^4 per rad with a load, else g), cable (m), g (m/s^2), masses (kg: vehicle, load, total); the height
# surface's 2 zeta wn (1/s) and wn^2 (1/s^2)
A_C, A_L, A_G, A_M, A_MLOAD, A_MT, A_LAM1, A_LAM0 = range(7, 15)
# the boundary layers (horizontal, height, yaw), sin of the tilt limit, the disturbance bound g tan(tilt_max) (m/s^2)
A_EPS_F, A_EPS_Z, A_EPS_PSI, A_SIN_TILT_MAX, A_DIST_MAX = range(15, 20)
# gains (AttitudeGains): switching amplitudes and reaching poles, the yaw integral gain, the observer's pole
A_RHO_Z, A_REACH_Z, A_RHO_F, A_REACH_F, A_K_PSI, A_RHO_PSI, A_REACH_PSI, A_WN_D = range(20, 28)
# smooth switching (1.0) or sign; thrust limits (N); tilt-rate limit (rad/s); the inner loops' attitude and yaw
# bandwidths (1/s), rate bandwidths (3, 1/s); the nominal inertia (3, kg m^2)
A_SMOOTH, A_THRUST_MIN, A_THRUST_MAX, A_TILT_RATE_MAX, A_W_I, A_W_PSI, A_B, A_I = 28, 29, 30, 31, 32, 33, 34, 37
# the hover command's thrust (N); the observer's longest step (s); 2.0, the exponent of Python's ``x ** 2``
A_HOVER, A_DIST_STEP, A_TWO = 40, 41, 42
# the tilt that balances the vehicle's drag per m/s (rad per m/s; 0: none in the law's model, smc_attitude._derived:
# with a load only)
A_DRAG_TILT = 43
ATTITUDE_SIZE = 44

# ---- a run's memory (smc.ControllerMemory) ---------------------------------------------------------------------------
# the error integrals (m s, rad s, m s, m s), the last step's time (s; NaN: none yet), the observer's disturbance
# (m/s^2) and velocity (m/s; NaN: not started)
AM_INT_Z, AM_INT_PSI, AM_INT_FX, AM_INT_FY, AM_T, AM_DIST_X, AM_DIST_Y, AM_VEL_X, AM_VEL_Y = range(9)
# scratch rewritten at every step (kept here so the step allocates nothing): the x and y error chains (5 each)
AM_EX, AM_EY = 9, 14
ATTITUDE_MEMORY = 19

# ---- the command -----------------------------------------------------------------------------------------------------
# thrust (N), the torques the rate loop is expected to apply (N m, body FLU), the attitude setpoint (ZYX, rad)
CMD_THRUST, CMD_TAU_PHI, CMD_TAU_THETA, CMD_TAU_PSI, CMD_PHI_SP, CMD_THETA_SP, CMD_PSI_SP = range(7)
COMMAND_SIZE = 7


# ---- Python side -----------------------------------------------------------------------------------------------------
def attitude_constants(params: AttitudeParams) -> np.ndarray:
    """The law's constants for ``params``: its derived figures as the scalar law computes them
    (``smc_attitude._derived``, cached per parameter object), so the two cannot drift apart."""
    from offboard.control import smc_attitude
    from offboard.control.disturbance_observer import DIST_STEP_MAX

    d = smc_attitude._derived(params)
    G, inner, v = params.gains, params.inner, params.vehicle
    k = list(d.k) + [0.0] * (5 - len(d.k))
    values: dict[int, float] = {A_WITH_LOAD: d.with_load, A_R: len(d.k)}
    values.update({A_K + i: k[i] for i in range(5)})
    values.update({A_C: d.c, A_L: d.l, A_G: d.g, A_M: d.M, A_MLOAD: d.m, A_MT: d.Mt, A_LAM1: d.lam1})
    values.update({A_LAM0: d.lam0, A_EPS_F: d.eps[0], A_EPS_Z: d.eps[1], A_EPS_PSI: d.eps[2]})
    values.update({A_SIN_TILT_MAX: d.sin_tilt_max, A_DIST_MAX: d.dist_max, A_RHO_Z: G.rho_z, A_REACH_Z: G.reach_z})
    values.update({A_RHO_F: G.rho_F, A_REACH_F: G.reach_F, A_K_PSI: G.k_psi, A_RHO_PSI: G.rho_psi})
    values.update({A_REACH_PSI: G.reach_psi, A_WN_D: G.wn_d, A_SMOOTH: params.switching == "smooth"})
    values.update({A_THRUST_MIN: params.thrust_min, A_THRUST_MAX: params.thrust_max})
    values.update(
        {A_TILT_RATE_MAX: params.tilt_rate_max, A_W_I: inner.attitude_bandwidth, A_W_PSI: inner.yaw_bandwidth}
    )
    values.update({A_B + i: inner.rate_bandwidth[i] for i in range(3)})
    values.update({A_I + i: v.inertia[i] for i in range(3)})
    values.update({A_HOVER: smc_attitude.hover_command(params).thrust, A_DIST_STEP: DIST_STEP_MAX, A_TWO: 2.0})
    values[A_DRAG_TILT] = d.drag_tilt
    return pack_constants(ATTITUDE_SIZE, values)


def attitude_memory() -> np.ndarray:
    """A run's memory before its first tick (``smc.ControllerMemory()``): integrals 0, no last step time, the
    disturbance observer not started."""
    mem = np.zeros(ATTITUDE_MEMORY)
    mem[AM_T] = mem[AM_VEL_X] = mem[AM_VEL_Y] = math.nan
    return mem


# ---- the law's parts ---------------------------------------------------------------------------------------------
#: ``smc.switching`` (the scalar law's own function, compiled as it is): ``s / (|s| + eps)`` when ``smooth``, else
#: ``sign(s)`` (0 at 0)
_switching = inline_kernel(smc.switching)


@inline_kernel
def _reference_is_finite(ref: np.ndarray) -> bool:
    """The law's screen of its reference: orders 0..5 of ``F_x`` and ``F_y``, 0..2 of the height, 0..1 of the
    heading, summed in the scalar law's order (an overflowing sum is refused too)."""
    sx, sy = 0.0, 0.0
    for i in range(6):
        sx = sx + ref[lay.REF_FX + i]
        sy = sy + ref[lay.REF_FY + i]
    total = sx + sy + ref[lay.REF_Z] + ref[lay.REF_Z + 1] + ref[lay.REF_Z + 2] + ref[lay.REF_PSI] + ref[lay.REF_PSI + 1]
    return math.isfinite(total)


@inline_kernel
def _height(c: np.ndarray, int_z: float, est: np.ndarray, ref: np.ndarray, n: tuple, smooth: bool) -> tuple:
    """The height law on the collective thrust (``smc_attitude.step``'s first block): (thrust N within the limits,
    whether it was clipped); ``int_z`` the updated height-error integral (m s), ``n`` the thrust direction (world)."""
    n1, n2, n3 = n[0], n[1], n[2]
    if c[A_WITH_LOAD] != 0.0:  # the cable from the planar angles (estimators.model.cable.cable_from_planar)
        ay, ax = est[kern.EST_ALPHA_Y], est[kern.EST_ALPHA_X]
        ty, tx = math.tan(ay), math.tan(ax)
        dty = est[kern.EST_ALPHA_Y_RATE] / math.cos(ay) ** c[A_TWO]
        dtx = est[kern.EST_ALPHA_X_RATE] / math.cos(ax) ** c[A_TWO]
        nn = math.sqrt(1.0 + ty * ty + tx * tx)
        r1, r2, r3 = ty / nn, tx / nn, -1.0 / nn
        dn = (ty * dty + tx * dtx) / nn
        q1, q2, q3 = (dty * nn - ty * dn) / (nn * nn), (dtx * nn - tx * dn) / (nn * nn), dn / (nn * nn)
        nr = n1 * r1 + n2 * r2 + n3 * r3
        g_z = (c[A_MT] * py_max(n3, 0.3) - c[A_MLOAD] * nr * r3) / (c[A_M] * c[A_MT])
        f_z = c[A_MLOAD] * c[A_L] * (q1 * q1 + q2 * q2 + q3 * q3) * r3 / c[A_MT] - c[A_G]
    else:
        g_z = py_max(n3, 0.3) / c[A_M]
        f_z = -c[A_G]
    e_z = est[kern.EST_Z] - ref[lay.REF_Z]
    e_zd = est[kern.EST_Z_RATE] - ref[lay.REF_Z + 1]
    s_z = e_zd + c[A_LAM1] * e_z + c[A_LAM0] * int_z
    sw_z = c[A_RHO_Z] * _switching(s_z, c[A_EPS_Z], smooth) + 0.5 * c[A_REACH_Z] * s_z
    thrust = (ref[lay.REF_Z + 2] - f_z - c[A_LAM1] * e_zd - c[A_LAM0] * e_z - sw_z) / g_z
    if thrust > c[A_THRUST_MAX]:
        return c[A_THRUST_MAX], True
    if thrust < c[A_THRUST_MIN]:
        return c[A_THRUST_MIN], True
    return thrust, False


@inline_kernel
def _observe_disturbance(c: np.ndarray, mem: np.ndarray, dt: float, v: tuple, acc: tuple) -> tuple:
    """``disturbance_observer.observe_disturbance`` (no load): (d_x, d_y m/s^2, v_hat_x, v_hat_y m/s, world) from
    the estimated velocity ``v`` (m/s) and the tilt's acceleration ``acc`` (m/s^2), the memory's previous ones."""
    wn_d = c[A_WN_D]
    mvx, mvy = mem[AM_VEL_X], mem[AM_VEL_Y]
    if wn_d <= 0.0:
        return 0.0, 0.0, mvx, mvy
    if not (math.isfinite(mvx) and math.isfinite(mvy)):  # the first step: start at rest
        return 0.0, 0.0, v[0], v[1]
    h = py_min(dt, c[A_DIST_STEP])
    ev_x, ev_y = v[0] - mvx, v[1] - mvy
    w2 = wn_d * wn_d
    d_x = mem[AM_DIST_X] + h * w2 * ev_x
    d_y = mem[AM_DIST_Y] + h * w2 * ev_y
    norm = py_hypot(d_x, d_y)
    if norm > c[A_DIST_MAX]:
        d_x, d_y = d_x * c[A_DIST_MAX] / norm, d_y * c[A_DIST_MAX] / norm
    vel_x = mvx + h * (acc[0] + d_x + 2.0 * wn_d * ev_x)
    vel_y = mvy + h * (acc[1] + d_y + 2.0 * wn_d * ev_y)
    return d_x, d_y, vel_x, vel_y


@inline_kernel
def _errors(c: np.ndarray, mem: np.ndarray, dt: float, est: np.ndarray, ref: np.ndarray, n: tuple) -> tuple:
    """The horizontal error chains into ``mem[AM_EX:]``, ``mem[AM_EY:]`` (with a load: ``F`` orders 0..4; without:
    the vehicle's position, velocity and acceleration ``g n / n3`` plus the observed disturbance) and (feed-forward
    x, y: ``F*^(5)`` or ``p*'''``; the tilt's own rate a' x, y, rad/s; the observer's d_x, d_y, v_x, v_y)."""
    ex, ey = mem[AM_EX : AM_EX + 5], mem[AM_EY : AM_EY + 5]
    if c[A_WITH_LOAD] != 0.0:
        for i in range(5):
            ex[i] = est[kern.EST_FX + i] - ref[lay.REF_FX + i]
            ey[i] = est[kern.EST_FY + i] - ref[lay.REF_FY + i]
        if c[A_DRAG_TILT] > 0.0:  # F^(4) = c (a + n - kt v), v the vehicle's velocity F' - l a'
            ex[4] = ex[4] - c[A_C] * c[A_DRAG_TILT] * (est[kern.EST_FX + 1] - c[A_L] * est[kern.EST_ALPHA_Y_RATE])
            ey[4] = ey[4] - c[A_C] * c[A_DRAG_TILT] * (est[kern.EST_FY + 1] - c[A_L] * est[kern.EST_ALPHA_X_RATE])
        obs = (mem[AM_DIST_X], mem[AM_DIST_Y], mem[AM_VEL_X], mem[AM_VEL_Y])
        rates = (-est[kern.EST_FX + 3] / c[A_G], -est[kern.EST_FY + 3] / c[A_G])  # a' = -F'''/g
        return ref[lay.REF_FX + 5], ref[lay.REF_FY + 5], rates, obs
    l = c[A_L]
    px, py = est[kern.EST_FX] - l * est[kern.EST_ALPHA_Y], est[kern.EST_FY] - l * est[kern.EST_ALPHA_X]
    vx, vy = (
        est[kern.EST_FX + 1] - l * est[kern.EST_ALPHA_Y_RATE],
        est[kern.EST_FY + 1] - l * est[kern.EST_ALPHA_X_RATE],
    )
    an3 = c[A_G] / py_max(n[2], 0.3)
    obs = _observe_disturbance(c, mem, dt, (vx, vy), (an3 * n[0], an3 * n[1]))
    ex[0], ex[1], ex[2] = px - ref[lay.REF_FX], vx - ref[lay.REF_FX + 1], an3 * n[0] + obs[0] - ref[lay.REF_FX + 2]
    ey[0], ey[1], ey[2] = py - ref[lay.REF_FY], vy - ref[lay.REF_FY + 1], an3 * n[1] + obs[1] - ref[lay.REF_FY + 2]
    return ref[lay.REF_FX + 3], ref[lay.REF_FY + 3], (0.0, 0.0), obs


@inline_kernel
def _axis(c: np.ndarray, e: np.ndarray, int_f: float, ff: float, smooth: bool) -> float:
    """One world axis's commanded derivative ``v_c`` (``F^(5)`` m/s^5 with a load, the jerk m/s^3 without) from its
    error chain ``e`` (r entries), the integral of its first (m s) and the feed-forward ``ff``, reaching its sliding
    surface ``sigma``; the scalar law's order of sums."""
    r = int(c[A_R])
    sigma = e[r - 1] + c[A_K] * int_f
    v_c = ff
    for i in range(r - 1):
        sigma += c[A_K + i + 1] * e[i]
    for i in range(r):
        v_c -= c[A_K + i] * e[i]
    v_c -= c[A_RHO_F] * _switching(sigma, c[A_EPS_F], smooth) + 0.5 * c[A_REACH_F] * sigma
    return v_c


@inline_kernel
def _thrust_direction_setpoint(c: np.ndarray, n: tuple, ndx: float, ndy: float) -> tuple:
    """The commanded world tilt rate (rad/s) clipped to the tilt-rate limit, then the thrust direction setpoint
    ``n + n'_c / w_i`` clipped to the tilt limit: (ndx, ndy, nsx, nsy, nsz, clipped)."""
    sat = False
    nd = py_hypot(ndx, ndy)
    if nd > c[A_TILT_RATE_MAX]:
        s = c[A_TILT_RATE_MAX] / nd
        ndx, ndy, sat = ndx * s, ndy * s, True
    wi = c[A_W_I]
    nsx = n[0] + ndx / wi
    nsy = n[1] + ndy / wi
    ns = py_hypot(nsx, nsy)
    if ns > c[A_SIN_TILT_MAX]:
        s = c[A_SIN_TILT_MAX] / ns
        nsx, nsy, sat = nsx * s, nsy * s, True
    nsz = math.sqrt(py_max(0.0, 1.0 - nsx * nsx - nsy * nsy))
    return ndx, ndy, nsx, nsy, nsz, sat


@inline_kernel
def _hover(c: np.ndarray, psi: float, u_out: np.ndarray) -> bool:
    """``smc_attitude.hover_command``: level at heading ``psi`` (0 if not finite) with the hover thrust; not
    saturated."""
    u_out[CMD_THRUST], u_out[CMD_TAU_PHI], u_out[CMD_TAU_THETA], u_out[CMD_TAU_PSI] = c[A_HOVER], 0.0, 0.0, 0.0
    u_out[CMD_PHI_SP], u_out[CMD_THETA_SP] = 0.0, 0.0
    u_out[CMD_PSI_SP] = psi if math.isfinite(psi) else 0.0
    return False


@pure_kernel
def attitude_step(
    c: np.ndarray, mem: np.ndarray, t: float, est: np.ndarray, ref: np.ndarray, u_out: np.ndarray
) -> bool:
    """``smc_attitude.step`` for one run at time ``t`` (s): the command (``CMD_*``: thrust N, the rate loop's
    expected torques N m body FLU, the attitude setpoint ZYX rad) into ``u_out`` (7,), ``mem`` (``AM_*``) updated;
    returns ``saturated`` (the thrust, the tilt rate or the tilt clipped)."""
    if not (estimate_is_finite(est) and math.isfinite(t) and _reference_is_finite(ref)):
        return _hover(c, est[kern.EST_PSI], u_out)
    smooth = c[A_SMOOTH] != 0.0
    dt = 0.0 if math.isnan(mem[AM_T]) else py_max(0.0, t - mem[AM_T])
    phi, theta, psi = est[kern.EST_PHI], est[kern.EST_THETA], est[kern.EST_PSI]
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    n = (sf * sp + cf * cp * st, cf * sp * st - cp * sf, cf * ct)  # the thrust direction, world
    int_z = mem[AM_INT_Z] + (est[kern.EST_Z] - ref[lay.REF_Z]) * dt
    thrust, sat_z = _height(c, int_z, est, ref, n, smooth)

    # horizontal: the commanded tilt rate per world axis, then the thrust direction setpoint
    ffx, ffy, rates, obs = _errors(c, mem, dt, est, ref, n)
    int_fx = mem[AM_INT_FX] + mem[AM_EX] * dt
    int_fy = mem[AM_INT_FY] + mem[AM_EY] * dt
    vx_c = _axis(c, mem[AM_EX : AM_EX + 5], int_fx, ffx, smooth)
    vy_c = _axis(c, mem[AM_EY : AM_EY + 5], int_fy, ffy, smooth)
    ndx, ndy = vx_c / c[A_C] - rates[0], vy_c / c[A_C] - rates[1]
    if c[A_DRAG_TILT] > 0.0:  # the rate of the tilt that balances the drag: kt p*''
        ndx = ndx + c[A_DRAG_TILT] * ref[lay.REF_FX + 2]
        ndy = ndy + c[A_DRAG_TILT] * ref[lay.REF_FY + 2]
    ndx, ndy, nsx, nsy, nsz, sat_f = _thrust_direction_setpoint(c, n, ndx, ndy)

    # yaw: the commanded heading rate and the heading setpoint
    e_psi = wrap_angle(psi - ref[lay.REF_PSI])
    int_psi = mem[AM_INT_PSI] + e_psi * dt
    s_psi = e_psi + c[A_K_PSI] * int_psi
    sw_psi = _switching(s_psi, c[A_EPS_PSI], smooth)
    psid_c = ref[lay.REF_PSI + 1] - c[A_K_PSI] * e_psi - c[A_RHO_PSI] * sw_psi - 0.5 * c[A_REACH_PSI] * s_psi
    psi_sp = wrap_angle(psi + psid_c / c[A_W_PSI])

    # the setpoint as ZYX angles: Rz(-psi_sp) n_sp = [cos(phi) sin(theta), -sin(phi), cos(phi) cos(theta)]
    cps, sps = math.cos(psi_sp), math.sin(psi_sp)
    m1 = cps * nsx + sps * nsy
    m2 = -sps * nsx + cps * nsy
    phi_sp = math.atan2(-m2, math.sqrt(m1 * m1 + nsz * nsz))
    theta_sp = math.atan2(m1, nsz)

    # the torques the rate loop is expected to apply for the small-angle body-rate command (for the filter)
    t1d = cp * ndx + sp * ndy  # heading-aligned tilt rate [theta', -phi']
    t2d = -sp * ndx + cp * ndy
    w1 = est[kern.EST_PHI_RATE] - st * est[kern.EST_PSI_RATE]
    w2 = cf * est[kern.EST_THETA_RATE] + sf * ct * est[kern.EST_PSI_RATE]
    w3 = -sf * est[kern.EST_THETA_RATE] + cf * ct * est[kern.EST_PSI_RATE]
    tau_phi = c[A_I] * c[A_B] * (-t2d - w1)
    tau_theta = c[A_I + 1] * c[A_B + 1] * (t1d - w2)
    tau_psi = c[A_I + 2] * c[A_B + 2] * (psid_c - w3)

    total = thrust + phi_sp + theta_sp + psi_sp + tau_phi + tau_theta + tau_psi + int_z + int_psi + int_fx + int_fy
    total += obs[0] + obs[1]
    if not math.isfinite(total):
        return _hover(c, psi, u_out)
    u_out[CMD_THRUST], u_out[CMD_TAU_PHI] = thrust, tau_phi
    u_out[CMD_TAU_THETA], u_out[CMD_TAU_PSI] = tau_theta, tau_psi
    u_out[CMD_PHI_SP], u_out[CMD_THETA_SP], u_out[CMD_PSI_SP] = phi_sp, theta_sp, psi_sp
    if not sat_z:  # a clipped loop's integral is held (no windup)
        mem[AM_INT_Z] = int_z
    if not sat_f:
        mem[AM_INT_FX], mem[AM_INT_FY] = int_fx, int_fy
    mem[AM_INT_PSI], mem[AM_T] = int_psi, t
    mem[AM_DIST_X], mem[AM_DIST_Y], mem[AM_VEL_X], mem[AM_VEL_Y] = obs[0], obs[1], obs[2], obs[3]
    return sat_z or sat_f
