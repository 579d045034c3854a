"""The measured-input Kalman filter (``estimators.filters.measured_kf``) as numba kernels over one run's state.

It follows ``estimators.filters.measured_kf`` (and through it ``small_kf``) operation by operation, the same
expressions in the same order, so that a run's estimate equals the scalar filter's to far below 1e-9
(``tests/test_compiled_engine.py``, the whole run against ``offboard.harness.sim.run``). Split by job as the scalar
filter is: this module the entry points (initialize, push a command, fuse a record, the estimate),
:mod:`.kf_layout` the arrays' layouts and constants, :mod:`.kf_predict` the blocks' models and prediction,
:mod:`.kf_update` the gated updates and the channels' adapted noise.

A run's filter is three arrays: ``c``, the constants (:func:`kf_constants`: the nominal vehicle, the tuning, the
gates, each channel's floor and ceiling; indices ``C_*``), and the state ``f`` (floats) and ``n`` (integers)
(:func:`kf_new_state`; indices ``F_*``, ``N_*``): the eight blocks (kinematics x, y, z ``[p, v, b]``, tilt x, y
``[n, n']``, heading ``[psi, psi']``, swing x, y ``[a, a', e]``; each its time, mean and the upper triangle of its
covariance, symmetric), the inputs,
the adapted position wander, the channels' innovation statistics, the ring of pushed thrusts and the gate counters.

Each of the scalar filter's branches is a branch here (the gate's accept / refuse / reopen, a block not advanced for
a step ``h <= 0``, the attitude records too close to pitched vertical to use, the series form of the pendulum
model, a stale IMU). ``kernels.maximum`` / ``kernels.minimum`` keep a NaN (Python's ``max()`` would not).

Units and frames as in ``estimators.filters.measured_kf``: SI, world NWU for the blocks, body FLU for the records'
rates and specific force; times in s. The records' timing (which are fused when, the block advances of a silent
stream) is the caller's (the sweep engine's ``offboard.harness.compiled.schedule``); a non-finite estimate is
returned as it is (the run has diverged); the nominal vehicle carries a load.
"""

from __future__ import annotations

import math

import numpy as np

from estimators import kernels as lay
from estimators.filters.compiled.kf_layout import (
    B_P,
    B_T,
    B_X,
    BLOCK_SIZE,
    C_ACCEL_GAIN,
    C_EXT_SIGNIFICANCE,
    C_EXTERNAL_FF,
    C_FLOOR,
    C_G,
    C_GATE3,
    C_GATE_REOPEN,
    C_I_PHI,
    C_I_THETA,
    C_K_C,
    C_K_G,
    C_K_L,
    C_L,
    C_M_OVER_M,
    C_MASS_VEHICLE,
    C_N_THRUST,
    C_Q_P_MIN,
    C_THRUST_JUMPS,
    C_VAR_BIAS,
    C_VAR_E,
    C_VAR_POS,
    C_VAR_PSI,
    C_VAR_PSI_RATE,
    C_VAR_SWING,
    C_VAR_SWING_RATE,
    C_VAR_TILT,
    C_VAR_TILT_RATE,
    C_VAR_VEL,
    CH_ACC,
    CH_ACC_IN,
    CH_GYRO_RATE,
    CH_GYRO_YAW_RATE,
    CH_LOAD,
    CH_POS_XY,
    CH_POS_Z,
    CH_TILT,
    CH_TILT_RATE,
    CH_VEL_XY,
    CH_VEL_Z,
    CH_YAW,
    CH_YAW_RATE,
    CHANNELS,
    F_BLOCKS,
    F_EY2,
    F_FZ,
    F_PUSH_COS,
    F_PUSH_PSI,
    F_PUSH_SIN,
    F_Q_P,
    F_T_IMU,
    F_THRUSTS,
    F_U,
    F_U_TILT,
    HEAD,
    KIN_X,
    KIN_Y,
    KIN_Z,
    N_CHANNELS,
    N_GATED_RUN,
    N_REFUSED,
    N_REOPENED,
    N_THRUST_POS,
    P00,
    P11,
    P22,
    S_ACC,
    S_ACC_IN,
    S_GYRO,
    S_LOAD,
    S_POS,
    S_PSI,
    S_TILT,
    S_Z,
    STREAMS,
    SWING_X,
    SWING_Y,
    TILT_X,
    TILT_Y,
    kf_constants,
    kf_new_state,
)
from estimators.filters.compiled.kf_predict import (
    _fresh,
    _mean3,
    _rate_mean,
    kf_advance,
)
from estimators.filters.compiled.kf_update import (
    _gated,
    _learn,
    _one,
    _pair,
    _row,
    _value,
)
from estimators.kernels import (
    ATT,
    IMU,
    POS,
    inline_kernel,
    maximum,
    minimum,
    pure_kernel,
    wrap_angle,
)
from estimators.model import flatness, rotations
from estimators.model.cable import cable_pull

#: the scalar path's own functions, compiled (the package's ``SHARED_SOURCES``): body rates to Euler rates, and the
#: world tilt and its rate from the attitude
_euler_rates = inline_kernel(rotations.euler_rates)
_world_tilt = inline_kernel(flatness.world_tilt)
#: the cable's pull as the accelerometer sees it: the scalar filter's own function, compiled
_cable_pull = inline_kernel(cable_pull)

#: this module's kernels: no kernel here creates, keeps or returns an array (``kernels.pure_kernel``)
_kernel = pure_kernel
_TX, _TY, _HD = (F_BLOCKS + BLOCK_SIZE * bi for bi in (TILT_X, TILT_Y, HEAD))  # the attitude blocks' offsets


# ---- the filter's entry points ------------------------------------------------------------------------------------
@_kernel
def _init_block(f, bi, t, x0, x1, x2, v0, v1, v2):
    """Block ``bi`` at time ``t`` with mean ``(x0, x1, x2)`` and diagonal prior variances ``(v0, v1, v2)`` (a
    two-state block: ``x2``, ``v2`` ignored)."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    f[o + B_T] = t
    f[o + B_X], f[o + B_X + 1] = x0, x1
    f[o + B_P + P00], f[o + B_P + P11] = v0, v1
    if bi < TILT_X or bi > HEAD:
        f[o + B_X + 2], f[o + B_P + P22] = x2, v2


@_kernel
def _planar(c, est, off):
    """``estimators.model.flatness.planar_state`` of the flat chain at ``est[off:off + 6]``: position (m), velocity
    (m/s), swing angle (rad) and rate, tilt (rad) and rate along that axis."""
    kl, kg, kc = c[C_K_L], c[C_K_G], c[C_K_C]
    f0, f1, f2, f3, f4, f5 = est[off], est[off + 1], est[off + 2], est[off + 3], est[off + 4], est[off + 5]
    a = -f2 / kg
    a_rate = -f3 / kg
    return f0 + kl * f2 / kg, f1 + kl * f3 / kg, a, a_rate, f4 / kc - a, f5 / kc - a_rate


@_kernel
def kf_initialize(c: np.ndarray, f: np.ndarray, n: np.ndarray, t: float, est_guess: np.ndarray) -> None:
    """Start at ``t`` (s) from the prior mean ``est_guess`` (``kernels.EST_*``; its flat chains, ``z``, ``z_rate``,
    ``psi`` and ``psi_rate`` are read) with the tuning's prior covariance; every input, statistic and counter reset."""
    f[:] = 0.0
    n[:] = 0
    px0, px1, px2, px3, px4, px5 = _planar(c, est_guess, lay.EST_FX)
    py0, py1, py2, py3, py4, py5 = _planar(c, est_guess, lay.EST_FY)
    vp, vv, vb = c[C_VAR_POS], c[C_VAR_VEL], c[C_VAR_BIAS]
    _init_block(f, KIN_X, t, px0, px1, 0.0, vp, vv, vb)
    _init_block(f, KIN_Y, t, py0, py1, 0.0, vp, vv, vb)
    _init_block(f, KIN_Z, t, est_guess[lay.EST_Z], est_guess[lay.EST_Z_RATE], 0.0, vp, vv, vb)
    _init_block(f, TILT_X, t, px4, px5, 0.0, c[C_VAR_TILT], c[C_VAR_TILT_RATE], 0.0)
    _init_block(f, TILT_Y, t, py4, py5, 0.0, c[C_VAR_TILT], c[C_VAR_TILT_RATE], 0.0)
    _init_block(
        f, HEAD, t, est_guess[lay.EST_PSI], est_guess[lay.EST_PSI_RATE], 0.0, c[C_VAR_PSI], c[C_VAR_PSI_RATE], 0.0
    )
    vs, vsr, ve = c[C_VAR_SWING], c[C_VAR_SWING_RATE], c[C_VAR_E]
    _init_block(f, SWING_X, t, px2, px3, 0.0, vs, vsr, ve)
    _init_block(f, SWING_Y, t, py2, py3, 0.0, vs, vsr, ve)
    for i in range(3):
        f[F_Q_P + i] = c[C_Q_P_MIN]
    f[F_T_IMU] = -math.inf
    f[F_FZ] = c[C_G]
    f[F_PUSH_PSI] = math.nan
    for ch in range(N_CHANNELS):
        f[F_EY2 + ch] = c[C_FLOOR + ch]
    n[N_THRUST_POS] = -1


@_kernel
def kf_push_command(
    c: np.ndarray, f: np.ndarray, n: np.ndarray, tau_phi: float, tau_theta: float, thrust: float
) -> None:
    """The command from now on (``push_command``): the torques (N m, body FLU) over the inertia, rotated to the world
    with the heading estimate, the tilt blocks' input (a non-finite torque keeps the previous one); the thrust (N)
    into the ring whose range widens the acceleration input's gate (a non-finite one keeps that slot's value)."""
    if c[C_THRUST_JUMPS] != 0.0:
        pos = n[N_THRUST_POS]
        n_thrust = int(c[C_N_THRUST])
        if pos < 0:  # the first command: the window starts full of it
            for k in range(n_thrust):
                f[F_THRUSTS + k] = thrust
            n[N_THRUST_POS] = 0
        else:
            if math.isfinite(thrust):
                f[F_THRUSTS + pos] = thrust
            n[N_THRUST_POS] = pos + 1 if pos + 1 < n_thrust else 0  # (pos + 1) % n_thrust, without a division
    t1, t2 = tau_theta / c[C_I_THETA], -tau_phi / c[C_I_PHI]
    psi = f[_HD + B_X]
    cached = f[F_PUSH_PSI]
    # (a NaN heading is recomputed every time: cos and sin give NaN again; -0.0 is not +0.0 here: sin keeps the sign)
    if psi != cached or math.copysign(1.0, psi) != math.copysign(1.0, cached):
        f[F_PUSH_PSI], f[F_PUSH_COS], f[F_PUSH_SIN] = psi, math.cos(psi), math.sin(psi)
    cp, sp = f[F_PUSH_COS], f[F_PUSH_SIN]
    if math.isfinite(tau_phi) and math.isfinite(tau_theta):
        f[F_U_TILT] = cp * t1 - sp * t2
        f[F_U_TILT + 1] = sp * t1 + cp * t2


@_kernel
def kf_fuse_gyro(c: np.ndarray, f: np.ndarray, n: np.ndarray, t: float, gyro: np.ndarray) -> None:
    """``fuse_gyro``: the IMU's body rates ``gyro`` (3,: p, q, r, rad/s, body FLU) sampled at ``t`` (s) as a
    measurement of the tilt rates and the heading rate, the attitude from the blocks themselves; skipped (after
    the blocks' advance) where the Euler rates are singular."""
    for bi in (TILT_X, TILT_Y, HEAD):
        kf_advance(c, f, n, bi, t)
    nx, ny, psi = f[_TX + B_X], f[_TY + B_X], f[_HD + B_X]
    cp, sp = math.cos(psi), math.sin(psi)
    theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
    if not abs(math.cos(theta)) >= 1e-3:
        return
    phi_rate, theta_rate, psi_rate = _euler_rates(phi, theta, gyro[0], gyro[1], gyro[2])
    _, _, nxd, nyd = _world_tilt(phi, theta, psi, phi_rate, theta_rate, psi_rate)
    _one(c, f, n, S_GYRO, TILT_X, 1, nxd, CH_GYRO_RATE)
    _one(c, f, n, S_GYRO, TILT_Y, 1, nyd, CH_GYRO_RATE)
    _one(c, f, n, S_GYRO, HEAD, 1, psi_rate, CH_GYRO_YAW_RATE)


@_kernel
def _fuse_pos(c, f, n, t, z):
    """A position / velocity record (x, y, z m, vx, vy, vz m/s, world NWU): the kinematic blocks' pairs."""
    for bi in (KIN_X, KIN_Y, KIN_Z):
        kf_advance(c, f, n, bi, t)
    _pair(c, f, n, S_POS, KIN_X, z[0], z[3], CH_POS_XY, CH_VEL_XY)
    _pair(c, f, n, S_POS, KIN_Y, z[1], z[4], CH_POS_XY, CH_VEL_XY)
    _pair(c, f, n, S_Z, KIN_Z, z[2], z[5], CH_POS_Z, CH_VEL_Z)


@_kernel
def _fuse_att(c, f, n, t, z):
    """An attitude record (phi, theta, psi rad, model-frame ZYX; p, q, r rad/s, body FLU): the world tilt and its
    rate to the tilt blocks, the heading and its rate to the heading block; skipped (no block advanced) where the
    Euler rates are singular."""
    phi, theta, psi = z[0], z[1], z[2]
    if not abs(math.cos(theta)) >= 1e-3:  # the scalar filter skips such a record ("not_used")
        return
    phi_rate, theta_rate, psi_rate = _euler_rates(phi, theta, z[3], z[4], z[5])
    nx, ny, nxd, nyd = _world_tilt(phi, theta, psi, phi_rate, theta_rate, psi_rate)
    for bi in (TILT_X, TILT_Y, HEAD):
        kf_advance(c, f, n, bi, t)
    _pair(c, f, n, S_TILT, TILT_X, nx, nxd, CH_TILT, CH_TILT_RATE)
    _pair(c, f, n, S_TILT, TILT_Y, ny, nyd, CH_TILT, CH_TILT_RATE)
    psi_est = f[_HD + B_X]
    _pair(c, f, n, S_PSI, HEAD, psi_est + wrap_angle(psi - psi_est), psi_rate, CH_YAW, CH_YAW_RATE)


@_kernel
def _thrust_jump(c, f):
    """The range of the pushed thrusts over the vehicle's mass (m/s^2): the jump of the measured acceleration the
    commands explain; NaN when a slot is NaN (numpy's max / min)."""
    lo = hi = f[F_THRUSTS]
    nan = lo != lo
    for k in range(1, int(c[C_N_THRUST])):
        v = f[F_THRUSTS + k]
        nan = nan or v != v
        hi = v if v > hi else hi
        lo = v if v < lo else lo
    return (math.nan if nan else hi - lo) / c[C_MASS_VEHICLE]


@_kernel
def _acc_input(c, f, n, t, u0, u1, u2):
    """The IMU's world acceleration ``(u0, u1, u2)`` (m/s^2, gravity removed) as the new acceleration input from
    ``t`` (s), unless a fresh input is there and this one is implausibly far from it (the chi-square gate of 3
    dof widened by the thrust jumps): then its gate counts the refusal and the previous input stays."""
    fresh = _fresh(c, f, t)
    var = _value(c, f, CH_ACC_IN)
    gate = c[C_GATE3]
    d0, d1, d2 = u0 - f[F_U], u1 - f[F_U + 1], u2 - f[F_U + 2]
    jump = _thrust_jump(c, f)
    plausible = 0.0 + d0 * d0 + d1 * d1 + d2 * d2 <= gate * var + jump * jump
    if fresh:  # the channel learns only where the input was fresh (the scalar filter's branch)
        for d in (d0, d1, d2):
            _learn(c, f, CH_ACC_IN, d, 0.0, var, gate)
        if plausible:
            n[N_GATED_RUN + S_ACC_IN] = 0
        elif not _gated(c, n, S_ACC_IN):
            return
    f[F_U], f[F_U + 1], f[F_U + 2] = u0, u1, u2
    f[F_T_IMU] = t


@_kernel
def _fuse_imu(c, f, n, t, z):
    """An IMU record (ax, ay, az: specific force m/s^2, body FLU): the swing blocks' measurement (the cable's pull),
    then the acceleration input (:func:`_acc_input`); its gyro is :func:`kf_fuse_gyro`'s."""
    for bi in (KIN_X, KIN_Y, KIN_Z, SWING_X, SWING_Y, TILT_X, TILT_Y, HEAD):
        kf_advance(c, f, n, bi, t)  # the tilt and heading: only those behind move
    tx, ty, hd = _TX, _TY, _HD
    nx = f[tx + B_X] - f[tx + B_X + 1] * (f[tx + B_T] - t)  # the attitude at the sample's time
    ny = f[ty + B_X] - f[ty + B_X + 1] * (f[ty + B_T] - t)
    psi = f[hd + B_X] - f[hd + B_X + 1] * (f[hd + B_T] - t)
    cp, sp = math.cos(psi), math.sin(psi)
    theta, phi = nx * cp + ny * sp, nx * sp - ny * cp
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
    ax, ay, az = z[0], z[1], z[2]
    hx = ct * ax + st * sf * ay + st * cf * az  # heading frame (yaw removed): f_h = Ry(theta) Rx(phi) f
    hy = cf * ay - sf * az
    hz = -st * ax + ct * sf * ay + ct * cf * az
    g = c[C_G]
    u0, u1 = cp * hx - sp * hy, sp * hx + cp * hy
    fz = f[F_FZ]
    fz = fz + c[C_ACCEL_GAIN] * (minimum(maximum(hz, 0.2 * g), 3.0 * g) - fz)
    f[F_FZ] = fz
    bx, by = cp * ax - sp * ay, sp * ax + cp * ay  # body-horizontal specific force, heading-rotated
    # the cable's pull linearized at the estimate, the scalar filter's rows in its order: the innovation z - h - e
    # as the row's z - H x; the tilt's own uncertainty adds to the noise
    mm, ln = c[C_M_OVER_M], c[C_L]
    sx, sy = F_BLOCKS + BLOCK_SIZE * SWING_X, F_BLOCKS + BLOCK_SIZE * SWING_Y
    a, ad = f[sx + B_X], f[sx + B_X + 1]
    h, h_a, h_ad, h_n = _cable_pull(mm, ln, a, ad, f[sy + B_X], f[sy + B_X + 1], nx, u0, u1, fz)
    _row(c, f, n, S_ACC, SWING_X, h_a, h_ad, 1.0, bx - h + h_a * a + h_ad * ad, CH_ACC, h_n * h_n * f[tx + B_P + P00])
    a, ad = f[sy + B_X], f[sy + B_X + 1]
    h, h_a, h_ad, h_n = _cable_pull(mm, ln, a, ad, f[sx + B_X], f[sx + B_X + 1], ny, u1, u0, fz)
    _row(c, f, n, S_ACC, SWING_Y, h_a, h_ad, 1.0, by - h + h_a * a + h_ad * ad, CH_ACC, h_n * h_n * f[ty + B_P + P00])
    _acc_input(c, f, n, t, u0, u1, hz - g)


@_kernel
def _fuse_load(c, f, n, t, z):
    """A cable-angle record (alpha_x, alpha_y, rad): swing x is alpha_y, swing y alpha_x."""
    kf_advance(c, f, n, SWING_X, t)
    kf_advance(c, f, n, SWING_Y, t)
    _row(c, f, n, S_LOAD, SWING_X, 1.0, 0.0, 0.0, z[1], CH_LOAD, 0.0)
    _row(c, f, n, S_LOAD, SWING_Y, 1.0, 0.0, 0.0, z[0], CH_LOAD, 0.0)


@_kernel
def kf_fuse(c: np.ndarray, f: np.ndarray, n: np.ndarray, kind: int, t: float, z: np.ndarray) -> None:
    """Fuse one record of ``kind`` (``kernels.POS``, ``ATT``, ``IMU``, ``LOAD``) sampled at ``t`` (s): ``z`` its
    ``kernels.FIELDS[kind]`` fields after its time, in the order of ``estimators.model.measurements``: POS x, y, z
    (m), vx, vy, vz (m/s); ATT phi, theta, psi (rad), p, q, r (rad/s); IMU ax, ay, az (m/s^2), gx, gy, gz (rad/s,
    fused by :func:`kf_fuse_gyro`); LOAD alpha_x, alpha_y (rad)."""
    if kind == POS:
        _fuse_pos(c, f, n, t, z)
    elif kind == ATT:
        _fuse_att(c, f, n, t, z)
    elif kind == IMU:
        _fuse_imu(c, f, n, t, z)
    else:
        _fuse_load(c, f, n, t, z)


# ---- output -------------------------------------------------------------------------------------------------------
@_kernel
def _chain(c, out, off, p, v, a, ad, nn, nd):
    """A horizontal axis's flat chain ``F .. F^(5)`` into ``out[off:off + 6]`` from position (m), velocity (m/s),
    swing angle and rate (rad, rad/s), tilt and rate (rad, rad/s) (``estimate_arrays``'s ``chain``)."""
    kl, kg, kc = c[C_K_L], c[C_K_G], c[C_K_C]
    out[off], out[off + 1] = p + kl * a, v + kl * ad
    out[off + 2], out[off + 3] = -kg * a, -kg * ad
    out[off + 4], out[off + 5] = kc * (a + nn), kc * (ad + nd)


@_kernel
def _external(c, f, bi, e):
    """The external acceleration ``e`` (m/s^2) of swing block ``bi`` beyond ``external_significance`` of its standard
    deviation (at the block's last update), as it enters F^(4): times ``g / l``."""
    s = math.sqrt(f[F_BLOCKS + BLOCK_SIZE * bi + B_P + P22])
    g_l = c[C_K_G] / c[C_K_L]
    return g_l * math.copysign(maximum(abs(e) - c[C_EXT_SIGNIFICANCE] * s, 0.0), e)


@_kernel
def kf_estimate(c: np.ndarray, f: np.ndarray, n: np.ndarray, t: float, est_out: np.ndarray) -> None:
    """``estimate_arrays(t)``: every block's mean predicted to ``t`` (s) with the inputs in force (the filter left as
    it is), as the estimate vector ``est_out`` (``kernels.EST_*``: flat chains, height, attitude, swing)."""
    px, vx, _ = _mean3(c, f, KIN_X, t)
    py, vy, _ = _mean3(c, f, KIN_Y, t)
    z, z_rate, _ = _mean3(c, f, KIN_Z, t)
    nx, nxd = _rate_mean(c, f, TILT_X, t)
    ny, nyd = _rate_mean(c, f, TILT_Y, t)
    psi, psi_rate = _rate_mean(c, f, HEAD, t)
    ay_, ayd, e_x = _mean3(c, f, SWING_X, t)
    ax_, axd, e_y = _mean3(c, f, SWING_Y, t)
    cp, sp = math.cos(psi), math.sin(psi)
    _chain(c, est_out, lay.EST_FX, px, vx, ay_, ayd, nx, nxd)
    _chain(c, est_out, lay.EST_FY, py, vy, ax_, axd, ny, nyd)
    if c[C_EXTERNAL_FF] != 0.0:  # MeasuredPrediction._control_state's external acceleration in F^(4)
        est_out[lay.EST_FX + 4] = est_out[lay.EST_FX + 4] + _external(c, f, SWING_X, e_x)
        est_out[lay.EST_FY + 4] = est_out[lay.EST_FY + 4] + _external(c, f, SWING_Y, e_y)
    est_out[lay.EST_Z], est_out[lay.EST_Z_RATE] = z, z_rate
    est_out[lay.EST_THETA] = nx * cp + ny * sp
    est_out[lay.EST_PHI] = nx * sp - ny * cp
    est_out[lay.EST_PSI] = wrap_angle(psi)
    est_out[lay.EST_THETA_RATE] = nxd * cp + nyd * sp + psi_rate * (-nx * sp + ny * cp)
    est_out[lay.EST_PHI_RATE] = nxd * sp - nyd * cp + psi_rate * (nx * cp + ny * sp)
    est_out[lay.EST_PSI_RATE] = psi_rate
    est_out[lay.EST_ALPHA_X], est_out[lay.EST_ALPHA_Y] = ax_, ay_
    est_out[lay.EST_ALPHA_X_RATE], est_out[lay.EST_ALPHA_Y_RATE] = axd, ayd


__all__ = [
    "CHANNELS",
    "C_GATE_REOPEN",
    "N_GATED_RUN",
    "N_REFUSED",
    "N_REOPENED",
    "STREAMS",
    "kf_advance",
    "kf_constants",
    "kf_estimate",
    "kf_fuse",
    "kf_fuse_gyro",
    "kf_initialize",
    "kf_new_state",
    "kf_push_command",
]
