"""The measured-input Kalman filter (``estimators.filters.measured_kf``) as numba kernels over one run's state.

Over 500 lines because it follows ``estimators.filters.measured_kf`` (and through it ``small_kf``) operation by
operation, the same expressions in the same order, so that a run's estimate equals the scalar filter's to far below
1e-9 (``tests/test_compiled_engine.py``, the whole run against ``offboard.harness.sim.run``); split, the kernels
would no longer read side by side with the code they mirror.

A run's filter is three arrays: ``c``, the constants (:func:`kf_constants`: the nominal vehicle, the tuning, the
gates, each channel's floor and ceiling; indices ``C_*``), and the state ``f`` (floats) and ``n`` (integers)
(:func:`kf_new_state`; indices ``F_*``, ``N_*``): the eight blocks (kinematics x, y, z ``[p, v, b]``, tilt x, y
``[n, n']``, heading ``[psi, psi']``, swing x, y ``[a, a', e]``; each its time, mean and the upper triangle of its
covariance, symmetric), the inputs,
the adapted position wander, the channels' innovation statistics, the ring of pushed thrusts and the gate counters.

Each of the scalar filter's branches is a branch here (the gate's accept / refuse / reopen, a block not advanced for
a step ``h <= 0``, the attitude records too close to pitched vertical to use, the series form of the pendulum
model, a stale IMU). ``layout.maximum`` / ``layout.minimum`` keep a NaN (Python's ``max()`` would not).

Units and frames as in ``estimators.filters.measured_kf``: SI, world NWU for the blocks, body FLU for the records'
rates and specific force; times in s. The records' timing (which are fused when, the
block advances of a silent stream) is the caller's (``offboard.harness.compiled.schedule``); a non-finite
estimate is returned as it is (the run has diverged); the nominal vehicle carries a load.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.filters.fusion import chi2_quantile
from estimators.filters.measured_kf import MeasuredTuning, thrust_window
from estimators.filters.measured_model import channel_floors, for_line
from estimators.model.cable import cable_pull
from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle
from offboard.harness.compiled.layout import (
    ATT,
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
    EST_THETA,
    EST_THETA_RATE,
    EST_Z,
    EST_Z_RATE,
    IMU,
    POS,
    inline_kernel,
    maximum,
    minimum,
    pure_kernel,
    wrap_angle,
)

#: this module's kernels: no kernel here creates, keeps or returns an array (``layout.pure_kernel``)
_kernel = pure_kernel
#: the cable's pull as the accelerometer sees it: the scalar filter's own function, compiled
_cable_pull = inline_kernel(cable_pull)

# ---- the constants vector c (kf_constants) ------------------------------------------------------------------------
# the nominal vehicle: inertia about body x, y (kg m^2), M (kg), g (m/s^2), l (m), m / M; flat constants l, g, c
C_I_PHI, C_I_THETA, C_MASS_VEHICLE, C_G, C_L, C_M_OVER_M, C_K_L, C_K_G, C_K_C = range(9)
# chi-square gates of 1 and 3 degrees of freedom; the channels' adaptation rate; the thrust window (pushes);
# the fusion horizon (s) and control rate (Hz) the filter was built for
C_GATE1, C_GATE3, C_ADAPT_RATE, C_N_THRUST, C_DELAY, C_RATE_HZ = range(9, 15)
# flags (1.0 / 0.0): load_sensor, tuning.fuse_gyro, thrust_explains_jumps, external_feedforward, tilt_command (the
# delay, rate, load_sensor and fuse_gyro are the schedule's business; tilt_command is not read: the kernels, as
# the sweep's filter, always take the commanded tilt acceleration; kf_constants refuses a tuning without it)
C_LOAD_SENSOR, C_FUSE_GYRO, C_THRUST_JUMPS, C_EXTERNAL_FF, C_TILT_COMMAND = range(15, 20)
# the tuning's densities and rates (MeasuredTuning's fields of the same names)
C_Q_V, C_Q_VZ, C_Q_V_NO_IMU, C_Q_B, C_Q_P_MIN, C_Q_P_MAX, C_WANDER_RATE = range(20, 27)
C_Q_N, C_Q_PSI, C_Q_A, C_Q_E, C_IMU_TIMEOUT, C_EXT_SIGNIFICANCE, C_GATE_REOPEN, C_ACCEL_GAIN = range(27, 35)
# the prior variances (the tuning's prior standard deviations squared)
C_VAR_POS, C_VAR_VEL, C_VAR_BIAS, C_VAR_TILT, C_VAR_TILT_RATE = range(35, 40)
C_VAR_PSI, C_VAR_PSI_RATE, C_VAR_SWING, C_VAR_SWING_RATE, C_VAR_E = range(40, 45)

# ---- measurement channels (each a floor, a ceiling and two running statistics) and gate streams -------------------
#: the measurement channels, each with its adapted noise (``MeasuredKalmanEstimator``'s ``_ch``), in the CH_* order
CHANNELS = (
    "pos_xy",
    "vel_xy",
    "pos_z",
    "vel_z",
    "tilt",
    "tilt_rate",
    "yaw",
    "yaw_rate",
    "acc",
    "acc_in",
    "load",
    "gyro_rate",
    "gyro_yaw_rate",
)
CH_POS_XY, CH_VEL_XY, CH_POS_Z, CH_VEL_Z, CH_TILT, CH_TILT_RATE, CH_YAW, CH_YAW_RATE = range(8)
CH_ACC, CH_ACC_IN, CH_LOAD, CH_GYRO_RATE, CH_GYRO_YAW_RATE = range(8, 13)
N_CHANNELS = len(CHANNELS)
C_FLOOR = 45  # N_CHANNELS floors (variances), then N_CHANNELS ceilings
C_CEILING = C_FLOOR + N_CHANNELS
C_SIZE = C_CEILING + N_CHANNELS

#: the gate streams (``MeasuredKalmanEstimator.stats``'s ``gated_<stream>``), in the S_* order
STREAMS = ("pos", "z", "tilt", "psi", "acc", "acc_in", "load", "gyro")
S_POS, S_Z, S_TILT, S_PSI, S_ACC, S_ACC_IN, S_LOAD, S_GYRO = range(8)

# ---- the state f (floats) and n (integers) ------------------------------------------------------------------------
#: the blocks, in the scalar filter's order (``measured_kf``'s ``_blocks``)
KIN_X, KIN_Y, KIN_Z, TILT_X, TILT_Y, HEAD, SWING_X, SWING_Y = range(8)
BLOCK_SIZE = 10  # a block's floats: its time, 3 means (2 used by the tilt and heading), 6 covariance entries
B_T, B_X, B_P = 0, 1, 4  # offsets in a block: time (s), mean, covariance's upper triangle
P00, P01, P02, P11, P12, P22 = range(6)  # offsets in the upper triangle (a two-state block uses P00, P01, P11)
F_BLOCKS = 0
F_U = F_BLOCKS + 8 * BLOCK_SIZE  # measured acceleration input, world NWU, gravity removed (3), m/s^2
F_U_TILT = F_U + 3  # commanded world tilt acceleration (x, y), rad/s^2
F_Q_P = F_U_TILT + 2  # adapted position wander density per axis (3), m^2/s
F_Y_MEAN = F_Q_P + 3  # running mean of each axis's position innovation (3), m
F_T_IMU = F_Y_MEAN + 3  # sampling time of the acceleration input in force (s; -inf: none)
F_FZ = F_T_IMU + 1  # low-passed vertical specific force g + u_z (world), m/s^2
F_EY2 = F_FZ + 1  # per channel, the running mean of the squared innovation
F_EHPH = F_EY2 + N_CHANNELS  # per channel, the running mean of the innovation's predicted variance
# the heading estimate the last command was rotated with (rad; NaN: none) and its cosine and sine: the heading block
# moves only when a record is fused, the commands come every tick
F_PUSH_PSI = F_EHPH + N_CHANNELS
F_PUSH_COS, F_PUSH_SIN = F_PUSH_PSI + 1, F_PUSH_PSI + 2
F_THRUSTS = F_PUSH_PSI + 3  # the ring of the last C_N_THRUST pushed thrusts, N (the state's last floats)
N_THRUST_POS = 0  # the ring's next slot (-1: no command pushed yet)
N_GATED_RUN = 1  # per stream, its updates refused in a row
N_REFUSED = N_GATED_RUN + 8  # per stream, refused updates since initialize (the scalar filter's gated_<stream>)
N_REOPENED = N_REFUSED + 8  # gates reopened since initialize (the scalar filter's gate_reopened)
N_SIZE = N_REOPENED + 1
_TX, _TY, _HD = (F_BLOCKS + BLOCK_SIZE * bi for bi in (TILT_X, TILT_Y, HEAD))  # the attitude blocks' offsets


def kf_constants(
    vehicle: Vehicle, tuning: MeasuredTuning, *, load_sensor: bool, delay_s: float = 0.012, rate_hz: float = 1000.0
) -> np.ndarray:
    """The constants ``c`` of the filter on the nominal ``vehicle`` (with a load) with ``tuning``, as
    ``BatchedMeasuredKalman(vehicle, B, load_sensor=..., tuning=..., delay_s=..., rate_hz=...)`` computes them."""
    if not vehicle.mass_load > 0.0:
        raise ValueError("the compiled filter needs a nominal vehicle with a load")
    if not tuning.tilt_command:  # (C_TILT_COMMAND is recorded, not read: the kernels have no white-n'' branch)
        raise ValueError("the compiled filter always takes the commanded tilt acceleration (tuning.tilt_command)")
    tn = for_line(tuning, vehicle.cable_length)
    k = flat_constants(vehicle)
    c = np.full(C_SIZE, np.nan)
    c[C_I_PHI], c[C_I_THETA] = vehicle.inertia[0], vehicle.inertia[1]
    c[C_MASS_VEHICLE], c[C_G], c[C_L] = vehicle.mass_vehicle, vehicle.gravity, vehicle.cable_length
    c[C_M_OVER_M] = vehicle.mass_load / vehicle.mass_vehicle
    c[C_K_L], c[C_K_G], c[C_K_C] = k.l, k.g, k.c
    c[C_GATE1], c[C_GATE3] = chi2_quantile(tn.gate_probability, 1), chi2_quantile(tn.gate_probability, 3)
    c[C_ADAPT_RATE], c[C_N_THRUST] = tn.noise_adapt_rate, thrust_window(tn, rate_hz)
    c[C_DELAY], c[C_RATE_HZ] = float(delay_s), float(rate_hz)
    flags = (load_sensor, tn.fuse_gyro, tn.thrust_explains_jumps, tn.external_feedforward, tn.tilt_command)
    c[C_LOAD_SENSOR : C_TILT_COMMAND + 1] = [1.0 if v else 0.0 for v in flags]
    c[C_Q_V : C_WANDER_RATE + 1] = (tn.q_v, tn.q_vz, tn.q_v_no_imu, tn.q_b, tn.q_p_min, tn.q_p_max, tn.wander_rate)
    c[C_Q_N : C_ACCEL_GAIN + 1] = (
        tn.q_n,
        tn.q_psi,
        tn.q_a,
        tn.q_e,
        tn.imu_timeout_s,
        tn.external_significance,
        tn.gate_reopen,
        tn.accel_gain_filter,
    )
    sds = (tn.prior_pos, tn.prior_vel, tn.prior_bias, tn.prior_tilt, tn.prior_tilt_rate, tn.prior_psi)
    sds += (tn.prior_psi_rate, tn.prior_swing, tn.prior_swing_rate, tn.prior_e)
    c[C_VAR_POS : C_VAR_E + 1] = [sd**2 for sd in sds]  # ** as _Block squares them (x ** 2 == x * x exactly)
    floors = channel_floors(tn)
    for i, name in enumerate(CHANNELS):
        c[C_FLOOR + i] = floors[name]
        c[C_CEILING + i] = floors[name] * tn.noise_ceiling**2
    assert np.isfinite(c).all(), "a constant slot was left unset"
    return c


def kf_new_state(consts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zero-filled state arrays ``(f, n)`` (float64, int64) of the filter of ``consts``; :func:`kf_initialize`
    fills them."""
    f = np.zeros(F_THRUSTS + int(consts[C_N_THRUST]))
    f[F_PUSH_PSI] = math.nan  # no heading cached yet
    return f, np.zeros(N_SIZE, dtype=np.int64)


# ---- numpy's elementwise semantics on scalars ---------------------------------------------------------------------
@inline_kernel
def _pk(i: int, j: int) -> int:
    """The offset of ``P[i][j]`` (= ``P[j][i]``) in a block's upper triangle (``P00`` .. ``P22``)."""
    if i > j:
        i, j = j, i
    return i * 3 - (i * (i - 1)) // 2 + (j - i)


# ---- small_kf over one run (the same expressions) -----------------------------------------------------------------
@_kernel
def _kinematic_model(h, q_v, q_b, q_p):
    """``[p, v, b]`` over ``h`` s (``small_kf.kinematic_model``): Phi (9, row-major), Gamma (3), Q's upper triangle
    (6); ``q_v`` ((m/s^2)^2/Hz), ``q_b`` ((m/s^3)^2/Hz), ``q_p`` (m^2/s)."""
    h2 = h * h
    h3 = h2 * h
    h4 = h3 * h
    phi = (1.0, h, -0.5 * h2, 0.0, 1.0, -h, 0.0, 0.0, 1.0)
    q = (
        q_p * h + q_v * h3 / 3.0 + q_b * h4 * h / 20.0,
        q_v * h2 / 2.0 + q_b * h4 / 8.0,
        -q_b * h3 / 6.0,
        q_v * h + q_b * h3 / 3.0,
        -q_b * h2 / 2.0,
        q_b * h,
    )
    return phi, (0.5 * h2, h, 0.0), q


@_kernel
def _pendulum_transition(h, w2):
    """The swing's ``a'' = -w2 a + f`` over ``h`` s (``w2`` 1/s^2): ``(f00, f01, f10, g0, g1)`` of Phi
    ``[[f00, f01, 0], [f10, f00, 0], [0, 0, 1]]`` and Gamma ``[g0, g1, 0]``; series where ``w h < 1e-3``."""
    w = math.sqrt(w2)
    wh = w * h
    h2 = h * h
    if wh < 1e-3:
        return 1.0 - 0.5 * w2 * h2, h, -w2 * h, 0.5 * h2, h
    c, s = math.cos(wh), math.sin(wh)
    return c, s / w, -w * s, (1.0 - c) / w2, s / w


@_kernel
def _pendulum_noise(h, w2, q_a):
    """``(Q_aa, Q_aa', Q_a'a')`` of the swing's white ``q_a`` ((rad/s^2)^2/Hz) over ``h`` s."""
    w = math.sqrt(w2)
    wh = w * h
    h2 = h * h
    if wh < 1e-3:
        return q_a * h2 * h / 3.0, q_a * h2 / 2.0, q_a * h
    s = math.sin(wh)
    s2 = math.sin(2.0 * wh) / (4.0 * w)
    return q_a * (0.5 * h - s2) / w2, q_a * s * s / (2.0 * w2), q_a * (0.5 * h + s2)


@_kernel
def _predict3(f, o, phi, gam, u, q):
    """A block's prediction of three states in place (``small_kf._predict3`` / ``propagate_cov3``): the block at
    ``f[o:]`` moved by ``Phi``, ``Gamma u`` (when ``u != 0``) and ``Q`` (upper triangle)."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = phi
    x, p = o + B_X, o + B_P
    x0, x1, x2 = f[x], f[x + 1], f[x + 2]
    y0 = f00 * x0 + f01 * x1 + f02 * x2
    y1 = f10 * x0 + f11 * x1 + f12 * x2
    y2 = f20 * x0 + f21 * x1 + f22 * x2
    if u != 0.0:
        y0, y1, y2 = y0 + gam[0] * u, y1 + gam[1] * u, y2 + gam[2] * u
    f[x], f[x + 1], f[x + 2] = y0, y1, y2
    p00, p01, p02, p11, p12, p22 = f[p + P00], f[p + P01], f[p + P02], f[p + P11], f[p + P12], f[p + P22]
    a00, a01, a02 = (
        f00 * p00 + f01 * p01 + f02 * p02,
        f00 * p01 + f01 * p11 + f02 * p12,
        f00 * p02 + f01 * p12 + f02 * p22,
    )
    a10, a11, a12 = (
        f10 * p00 + f11 * p01 + f12 * p02,
        f10 * p01 + f11 * p11 + f12 * p12,
        f10 * p02 + f11 * p12 + f12 * p22,
    )
    a20, a21, a22 = (
        f20 * p00 + f21 * p01 + f22 * p02,
        f20 * p01 + f21 * p11 + f22 * p12,
        f20 * p02 + f21 * p12 + f22 * p22,
    )
    q00, q01, q02, q11, q12, q22 = q
    f[p + P00] = a00 * f00 + a01 * f01 + a02 * f02 + q00
    f[p + P01] = a00 * f10 + a01 * f11 + a02 * f12 + q01
    f[p + P02] = a00 * f20 + a01 * f21 + a02 * f22 + q02
    f[p + P11] = a10 * f10 + a11 * f11 + a12 * f12 + q11
    f[p + P12] = a10 * f20 + a11 * f21 + a12 * f22 + q12
    f[p + P22] = a20 * f20 + a21 * f21 + a22 * f22 + q22


@_kernel
def _predict2(f, o, h, q, g0, g1, u):
    """A block's prediction of two states in place with ``_rate_model(h, q)`` (the generic loop: Python's
    ``sum`` starts from 0, hence the ``0.0 +``, which turns a -0.0 into 0.0 as it does), and the input column
    ``[g0, g1]`` of ``u`` moving the mean only (none: ``u = 0``)."""
    h2 = h * h
    f00, f01, f10, f11 = 1.0, h, 0.0, 1.0
    q00, q01, q11 = q * h2 * h / 3.0, q * h2 / 2.0, q * h
    x, p = o + B_X, o + B_P
    x0, x1 = f[x], f[x + 1]
    y0, y1 = 0.0 + f00 * x0 + f01 * x1, 0.0 + f10 * x0 + f11 * x1
    if u != 0.0:
        y0, y1 = y0 + g0 * u, y1 + g1 * u
    f[x], f[x + 1] = y0, y1
    p00, p01, p11 = f[p + P00], f[p + P01], f[p + P11]
    a00, a01 = 0.0 + f00 * p00 + f01 * p01, 0.0 + f00 * p01 + f01 * p11  # Phi P
    a10, a11 = 0.0 + f10 * p00 + f11 * p01, 0.0 + f10 * p01 + f11 * p11
    f[p + P00] = 0.0 + a00 * f00 + a01 * f01 + q00  # (Phi P) Phi^T + Q
    f[p + P01] = 0.0 + a00 * f10 + a01 * f11 + q01
    f[p + P11] = 0.0 + a10 * f10 + a11 * f11 + q11


@_kernel
def _correct(f, o, three, ph0, ph1, ph2, y, s):
    """The correction of an accepted update in place: ``x += ph y / s``, ``P -= ph ph^T / s`` with
    ``ph = P h`` (taken before the update), innovation ``y`` and its variance ``s``; ``ph2`` unused for a
    two-state block (``three`` False)."""
    x, p = o + B_X, o + B_P
    f[x] = f[x] + ph0 * y / s
    k0 = ph0 / s
    f[p + P00] = f[p + P00] - k0 * ph0
    f[p + P01] = f[p + P01] - k0 * ph1
    f[x + 1] = f[x + 1] + ph1 * y / s
    k1 = ph1 / s
    if not three:
        f[p + P11] = f[p + P11] - k1 * ph1
        return
    f[p + P02] = f[p + P02] - k0 * ph2
    f[p + P11] = f[p + P11] - k1 * ph1
    f[p + P12] = f[p + P12] - k1 * ph2
    f[x + 2] = f[x + 2] + ph2 * y / s
    k2 = ph2 / s
    f[p + P22] = f[p + P22] - k2 * ph2


@_kernel
def _update_one(f, bi, i, z, r, gate):
    """One state's update: block ``bi``'s state ``i`` measured as ``z`` with variance ``r``, gated at
    ``gate`` (chi-square, 1 dof); True when accepted (else nothing changes)."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    p = o + B_P
    s = f[p + _pk(i, i)] + r
    y = z - f[o + B_X + i]
    if not (s > 0.0 and y * y <= gate * s):
        return False
    three = bi < TILT_X or bi > HEAD
    ph2 = f[p + _pk(2, i)] if three else 0.0
    _correct(f, o, three, f[p + _pk(0, i)], f[p + _pk(1, i)], ph2, y, s)
    return True


@_kernel
def _update_row(f, bi, h0, h1, h2, z, r, gate):
    """A row's update on three-state block ``bi``: ``z = h . x + noise(r)``, gated at ``gate``; True when
    accepted."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    x, p = o + B_X, o + B_P
    p00, p01, p02, p11, p12, p22 = f[p + P00], f[p + P01], f[p + P02], f[p + P11], f[p + P12], f[p + P22]
    ph0 = 0.0 + p00 * h0 + p01 * h1 + p02 * h2
    ph1 = 0.0 + p01 * h0 + p11 * h1 + p12 * h2
    ph2 = 0.0 + p02 * h0 + p12 * h1 + p22 * h2
    s = 0.0 + h0 * ph0 + h1 * ph1 + h2 * ph2 + r
    y = z - (0.0 + h0 * f[x] + h1 * f[x + 1] + h2 * f[x + 2])
    if not (s > 0.0 and y * y <= gate * s):
        return False
    _correct(f, o, True, ph0, ph1, ph2, y, s)
    return True


# ---- channels and gates (BatchedMeasuredKalman's methods of the same names) ---------------------------------------
@_kernel
def _value(c, f, ch):
    """Channel ``ch``'s adapted variance: ``E[y^2] - E[h P h]`` between its floor and its ceiling (NaN: the floor)."""
    v = f[F_EY2 + ch] - f[F_EHPH + ch]
    if v > c[C_CEILING + ch]:
        return c[C_CEILING + ch]
    return v if v > c[C_FLOOR + ch] else c[C_FLOOR + ch]


@_kernel
def _learn(c, f, ch, y, hph, r, gate):
    """Channel ``ch`` learns innovation ``y`` of predicted variance ``hph + r``, its square clipped at the gate."""
    rate = c[C_ADAPT_RATE]
    y2 = minimum(y * y, gate * (hph + r))
    e = f[F_EY2 + ch]
    f[F_EY2 + ch] = e + rate * (y2 - e)
    h = f[F_EHPH + ch]
    f[F_EHPH + ch] = h + rate * (hph - h)


@_kernel
def _gated(c, n, stream):
    """A refused update of ``stream`` counted; True when its gate reopens (refused more than ``gate_reopen`` times in
    a row: the update is then made ungated; the run counter stays, as in the scalar filter)."""
    n[N_REFUSED + stream] += 1
    run = n[N_GATED_RUN + stream] + 1
    if run <= c[C_GATE_REOPEN]:
        n[N_GATED_RUN + stream] = run
        return False
    n[N_REOPENED] += 1
    return True


@_kernel
def _one(c, f, n, stream, bi, i, z, ch):
    """``_one``: the gated update of block ``bi``'s state ``i`` measured as ``z`` on channel ``ch``; True when
    accepted."""
    r = _value(c, f, ch)
    o = F_BLOCKS + BLOCK_SIZE * bi
    pii = f[o + B_P + _pk(i, i)]
    y = z - f[o + B_X + i]
    gate = c[C_GATE1]
    ok = _update_one(f, bi, i, z, r, gate)
    if not ok and _gated(c, n, stream):
        _update_one(f, bi, i, z, r, math.inf)
    _learn(c, f, ch, y, pii, r, gate)
    if ok:
        n[N_GATED_RUN + stream] = 0
    return ok


@_kernel
def _row(c, f, n, stream, bi, h0, h1, h2, z, ch, extra_r):
    """``_row``: the gated update ``z = h . x`` of three-state block ``bi`` on channel ``ch`` plus ``extra_r`` of
    variance; True when accepted."""
    r = _value(c, f, ch) + extra_r
    o = F_BLOCKS + BLOCK_SIZE * bi
    x, p = o + B_X, o + B_P
    p00, p01, p02, p11, p12, p22 = f[p + P00], f[p + P01], f[p + P02], f[p + P11], f[p + P12], f[p + P22]
    hph = 0.0 + h0 * (0.0 + p00 * h0 + p01 * h1 + p02 * h2) + h1 * (0.0 + p01 * h0 + p11 * h1 + p12 * h2)
    hph = hph + h2 * (0.0 + p02 * h0 + p12 * h1 + p22 * h2)
    y = z - (0.0 + h0 * f[x] + h1 * f[x + 1] + h2 * f[x + 2])
    gate = c[C_GATE1]
    ok = _update_row(f, bi, h0, h1, h2, z, r, gate)
    if not ok and _gated(c, n, stream):
        _update_row(f, bi, h0, h1, h2, z, r, math.inf)
    _learn(c, f, ch, y, hph + extra_r, r - extra_r, gate)
    if ok:
        n[N_GATED_RUN + stream] = 0
    return ok


@_kernel
def _learn_wander(c, f, i, y, s):
    """Axis ``i``'s position wander density from its innovation ``y`` of variance ``s`` (``_learn_wander``)."""
    lam = c[C_WANDER_RATE]
    ym = f[F_Y_MEAN + i]
    rs = math.sqrt(s)
    m = ym + lam * (maximum(-3.0, minimum(3.0, y / rs)) * rs - ym)
    f[F_Y_MEAN + i] = m
    q = f[F_Q_P + i] * (1.2 if m * m > 9.0 * s * lam / (2.0 - lam) else 0.995)
    f[F_Q_P + i] = minimum(maximum(q, c[C_Q_P_MIN]), c[C_Q_P_MAX])


@_kernel
def _pair(c, f, n, stream, bi, z0, z1, c0, c1):
    """``_pair``: block ``bi``'s states 0 and 1 measured as ``z0``, ``z1`` on channels ``c0``, ``c1``, one at a time;
    a kinematic block's position innovation adapts its axis's wander."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    y0, s0 = z0 - f[o + B_X], f[o + B_P + P00] + _value(c, f, c0)
    _one(c, f, n, stream, bi, 0, z0, c0)
    if bi < TILT_X:
        _learn_wander(c, f, bi, y0, s0)
    _one(c, f, n, stream, bi, 1, z1, c1)


# ---- models and prediction ----------------------------------------------------------------------------------------
@_kernel
def _fresh(c, f, t):
    """The acceleration input is in force at ``t`` (s): sampled at most ``imu_timeout_s`` before."""
    return t - f[F_T_IMU] <= c[C_IMU_TIMEOUT]


@_kernel
def _swing_input(c, f, bi, t):
    """Swing block ``bi``'s squared frequency ``w2`` (1/s^2) and input ``f`` (rad/s^2) at block time ``t``
    (``_model``'s swing branch: none and ``w2 = g / l`` without a fresh input)."""
    fresh = _fresh(c, f, t)
    g, l = c[C_G], c[C_L]
    uz = f[F_U + 2] if fresh else 0.0
    w2 = maximum(g + uz, 0.2 * g) / l
    axis = bi - SWING_X
    u = f[F_U + axis] - f[F_BLOCKS + BLOCK_SIZE * axis + B_X + 2] if fresh else 0.0
    return w2, -u / l


@_kernel
def kf_advance(c: np.ndarray, f: np.ndarray, n: np.ndarray, bi: int, t: float) -> None:
    """Predict block ``bi`` (``KIN_X`` .. ``SWING_Y``) to ``t`` (s) with the inputs in force (``advance``; a step
    ``h <= 0`` leaves it). The schedule's block advance event (code ``layout.ADVANCE + bi``)."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    tb = f[o + B_T]
    h = t - tb
    if not h > 0.0:
        return
    if bi < TILT_X:
        fresh = _fresh(c, f, tb)
        q_v = (c[C_Q_V] if bi < KIN_Z else c[C_Q_VZ]) if fresh else c[C_Q_V_NO_IMU]
        phi, gam, q = _kinematic_model(h, q_v, c[C_Q_B], f[F_Q_P + bi])
        _predict3(f, o, phi, gam, f[F_U + bi] if fresh else 0.0, q)
    elif bi > HEAD:
        w2, u = _swing_input(c, f, bi, tb)
        f00, f01, f10, g0, g1 = _pendulum_transition(h, w2)
        qaa, qad, qdd = _pendulum_noise(h, w2, c[C_Q_A])
        phi = (f00, f01, 0.0, f10, f00, 0.0, 0.0, 0.0, 1.0)
        _predict3(f, o, phi, (g0, g1, 0.0), u, (qaa, qad, 0.0, qdd, 0.0, c[C_Q_E] * h))
    elif bi == HEAD:
        _predict2(f, o, h, c[C_Q_PSI], 0.0, 0.0, 0.0)
    else:  # a tilt block: the commanded acceleration as its input
        _predict2(f, o, h, c[C_Q_N], 0.5 * h * h, h, f[F_U_TILT + bi - TILT_X])
    f[o + B_T] = t


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
    """Start at ``t`` (s) from the prior mean ``est_guess`` (``layout.EST_*``; its flat chains, ``z``, ``z_rate``,
    ``psi`` and ``psi_rate`` are read) with the tuning's prior covariance; every input, statistic and counter reset."""
    f[:] = 0.0
    n[:] = 0
    px0, px1, px2, px3, px4, px5 = _planar(c, est_guess, EST_FX)
    py0, py1, py2, py3, py4, py5 = _planar(c, est_guess, EST_FY)
    vp, vv, vb = c[C_VAR_POS], c[C_VAR_VEL], c[C_VAR_BIAS]
    _init_block(f, KIN_X, t, px0, px1, 0.0, vp, vv, vb)
    _init_block(f, KIN_Y, t, py0, py1, 0.0, vp, vv, vb)
    _init_block(f, KIN_Z, t, est_guess[EST_Z], est_guess[EST_Z_RATE], 0.0, vp, vv, vb)
    _init_block(f, TILT_X, t, px4, px5, 0.0, c[C_VAR_TILT], c[C_VAR_TILT_RATE], 0.0)
    _init_block(f, TILT_Y, t, py4, py5, 0.0, c[C_VAR_TILT], c[C_VAR_TILT_RATE], 0.0)
    _init_block(f, HEAD, t, est_guess[EST_PSI], est_guess[EST_PSI_RATE], 0.0, c[C_VAR_PSI], c[C_VAR_PSI_RATE], 0.0)
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
    mp, mq, mr = gyro[0], gyro[1], gyro[2]
    sf, cf, ct = math.sin(phi), math.cos(phi), math.cos(theta)  # estimators.model.rotations.euler_rates
    tt = math.tan(theta)
    phi_rate, theta_rate, psi_rate = mp + sf * tt * mq + cf * tt * mr, cf * mq - sf * mr, (sf * mq + cf * mr) / ct
    nxd = theta_rate * cp + phi_rate * sp - psi_rate * (theta * sp - phi * cp)  # world_tilt's rates
    nyd = theta_rate * sp - phi_rate * cp + psi_rate * (theta * cp + phi * sp)
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
    phi, theta, psi, mp, mq, mr = z[0], z[1], z[2], z[3], z[4], z[5]
    sf, cf, ct = math.sin(phi), math.cos(phi), math.cos(theta)
    if not abs(ct) >= 1e-3:  # the scalar filter skips such a record ("not_used")
        return
    tt = math.tan(theta)
    phi_rate = mp + sf * tt * mq + cf * tt * mr
    theta_rate = cf * mq - sf * mr
    psi_rate = (sf * mq + cf * mr) / ct
    cp, sp = math.cos(psi), math.sin(psi)  # estimators.model.flatness.world_tilt
    nx = theta * cp + phi * sp
    ny = theta * sp - phi * cp
    nxd = theta_rate * cp + phi_rate * sp - psi_rate * ny
    nyd = theta_rate * sp - phi_rate * cp + psi_rate * nx
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
    """Fuse one record of ``kind`` (``layout.POS``, ``ATT``, ``IMU``, ``LOAD``) sampled at ``t`` (s): ``z`` its
    ``layout.FIELDS[kind]`` fields after its time, in the order of ``estimators.model.measurements``: POS x, y, z
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
def _rate_mean(c, f, bi, t):
    """A tilt or heading block's mean at ``t`` (s): the commanded tilt acceleration held, the heading rate held."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    x0, x1 = f[o + B_X], f[o + B_X + 1]
    h = t - f[o + B_T]
    if not h > 0.0:
        return x0, x1
    if bi == HEAD:
        return x0 + h * x1, x1
    u = f[F_U_TILT + bi - TILT_X]
    return x0 + h * x1 + 0.5 * h * h * u, x1 + h * u


@_kernel
def _kin_mean(c, f, bi, t):
    """A kinematic block's mean at ``t`` (s), the acceleration input in force held."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    tb = f[o + B_T]
    x0, x1, x2 = f[o + B_X], f[o + B_X + 1], f[o + B_X + 2]
    h = t - tb
    if not h > 0.0:
        return x0, x1, x2
    acc = (f[F_U + bi] if _fresh(c, f, tb) else 0.0) - x2
    return x0 + h * x1 + 0.5 * h * h * acc, x1 + h * acc, x2


@_kernel
def _swing_mean(c, f, bi, t):
    """A swing block's mean at ``t`` (s): its model's transition and input (``Phi x + Gamma u``, the scalar filter's
    three-state sums with the model's zeros and ones)."""
    o = F_BLOCKS + BLOCK_SIZE * bi
    tb = f[o + B_T]
    x0, x1, x2 = f[o + B_X], f[o + B_X + 1], f[o + B_X + 2]
    h = t - tb
    if not h > 0.0:
        return x0, x1, x2
    w2, u = _swing_input(c, f, bi, tb)
    f00, f01, f10, g0, g1 = _pendulum_transition(h, w2)
    y0 = f00 * x0 + f01 * x1 + 0.0 * x2
    y1 = f10 * x0 + f00 * x1 + 0.0 * x2
    y2 = 0.0 * x0 + 0.0 * x1 + 1.0 * x2
    if u != 0.0:
        y0, y1, y2 = y0 + g0 * u, y1 + g1 * u, y2 + 0.0 * u
    return y0, y1, y2


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
    it is), as the estimate vector ``est_out`` (``layout.EST_*``: flat chains, height, attitude, swing)."""
    px, vx, _ = _kin_mean(c, f, KIN_X, t)
    py, vy, _ = _kin_mean(c, f, KIN_Y, t)
    z, z_rate, _ = _kin_mean(c, f, KIN_Z, t)
    nx, nxd = _rate_mean(c, f, TILT_X, t)
    ny, nyd = _rate_mean(c, f, TILT_Y, t)
    psi, psi_rate = _rate_mean(c, f, HEAD, t)
    ay_, ayd, e_x = _swing_mean(c, f, SWING_X, t)
    ax_, axd, e_y = _swing_mean(c, f, SWING_Y, t)
    cp, sp = math.cos(psi), math.sin(psi)
    _chain(c, est_out, EST_FX, px, vx, ay_, ayd, nx, nxd)
    _chain(c, est_out, EST_FY, py, vy, ax_, axd, ny, nyd)
    if c[C_EXTERNAL_FF] != 0.0:  # MeasuredPrediction._control_state's external acceleration in F^(4)
        est_out[EST_FX + 4] = est_out[EST_FX + 4] + _external(c, f, SWING_X, e_x)
        est_out[EST_FY + 4] = est_out[EST_FY + 4] + _external(c, f, SWING_Y, e_y)
    est_out[EST_Z], est_out[EST_Z_RATE] = z, z_rate
    est_out[EST_THETA] = nx * cp + ny * sp
    est_out[EST_PHI] = nx * sp - ny * cp
    est_out[EST_PSI] = wrap_angle(psi)
    est_out[EST_THETA_RATE] = nxd * cp + nyd * sp + psi_rate * (-nx * sp + ny * cp)
    est_out[EST_PHI_RATE] = nxd * sp - nyd * cp + psi_rate * (nx * cp + ny * sp)
    est_out[EST_PSI_RATE] = psi_rate
    est_out[EST_ALPHA_X], est_out[EST_ALPHA_Y] = ax_, ay_
    est_out[EST_ALPHA_X_RATE], est_out[EST_ALPHA_Y_RATE] = axd, ayd


__all__ = [
    "CHANNELS",
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
