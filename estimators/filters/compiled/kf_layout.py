"""The measured-input filter's arrays in a compiled run (:mod:`.kf`): the constants ``c`` (:func:`kf_constants`:
the nominal vehicle, the tuning, the gates, each channel's floor and ceiling; indices ``C_*``) and the state ``f``
(floats) and ``n`` (integers) (:func:`kf_new_state`; indices ``F_*``, ``N_*``), with the measurement channels
(``CH_*``), the gate streams (``S_*``) and the blocks (``KIN_X`` .. ``SWING_Y``) that index them.

A block is ``BLOCK_SIZE`` floats of ``f``: its time (s), its mean (2 or 3 states) and the upper triangle of its
covariance (symmetric; :func:`_pk` the offset of an entry). Units as in ``estimators.filters.measured_kf``.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.filters.fusion import chi2_quantile
from estimators.filters.measured_kf import MeasuredTuning, thrust_window
from estimators.filters.measured_model import channel_floors, for_line
from estimators.kernels import inline_kernel
from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle

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
