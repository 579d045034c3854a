"""PX4's attitude path of a compiled run (actuators ``px4-attitude``, the ``smc-attitude`` row): the attitude setpoint
through PX4's quaternion attitude P, rate PID, sequential-desaturation allocator and the motors with their lag
(``sim_bridge.inner.px4_attitude_path.Px4AttitudePath`` and ``sim_bridge.inner.px4_inner``), for one run, with the
scalar classes' expressions in their order and their schedule on the plant's steps: attitude P on every fourth
step, rate PID and allocator on every second, the motors on every step.

The path's constants are a float array indexed by ``PX_*`` (:func:`px4_constants`, read from a ``Px4AttitudePath``
built for the run's true vehicle, as the scalar path builds it), its state a caller-owned float array indexed by
``PS_*`` (:func:`px4_state`). Frames as the scalar classes: the setpoint and the plant state in the model frame
(world NWU, body FLU), PX4's rates and normalized torques in body FRD; the wrench out ``(thrust N, tau_x, tau_y,
tau_z N m, FLU)``. Python's ``min`` / ``max`` are mirrored by ``kernels.py_min`` / ``py_max``; the yaw-rate
feed-forward, always zero on this path (``Px4AttitudePath.set_setpoint``'s default), is left out.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators.kernels import inline_kernel, pack_constants, pure_kernel, py_max, py_min
from estimators.model import frames, rotations
from sim_bridge.inner import px4_inner
from sim_bridge.plant.compiled.plant import body_rates

# ---- constants ------------------------------------------------------------------------------------------------------
# attitude P: gains roll, pitch, yaw (1/s; the yaw's divided by the weight), MC_YAW_WEIGHT, rate limits (rad/s)
PX_ATT_GAIN, PX_YAW_WEIGHT, PX_RATE_LIMIT = 0, 3, 4
# rate PID: its period (s), then per axis (roll, pitch, yaw; FRD) P, I, D, FF (normalized torque per rad/s, times
# MC_*RATE_K) and the integrator's limit; 1 / 400 deg (1/rad), the integrator's large-error reduction
PX_RATE_DT, PX_KP, PX_KI, PX_KD, PX_KFF, PX_INT_LIM, PX_INV_400DEG = 7, 8, 11, 14, 17, 20, 23
# the two-pole low passes of the gyro and of its derivative (LP_* each)
PX_GYRO_LP, PX_DGYRO_LP = 24, 30
LP_ON, LP_B0, LP_B1, LP_B2, LP_A1, LP_A2 = range(6)
# the allocator: MC_AIRMODE; its normalized columns per motor (4 each): roll, pitch, yaw, thrust; the normalized
# torque of each motor command (3 rows of 4: roll, pitch, yaw)
PX_AIRMODE, PX_M_ROLL, PX_M_PITCH, PX_M_YAW, PX_M_THRUST, PX_EFF = 36, 37, 41, 45, 49, 53
# the motors: positions x, y (m, FRD; 4 each), spin (+-1), one motor's largest thrust (N), the yaw moment
# coefficient (m), the lag's factor per plant step
PX_POS_X, PX_POS_Y, PX_SPIN, PX_FMAX, PX_CQ, PX_ALPHA = 65, 69, 73, 77, 78, 79
# the path: the collective thrust limit (N); the tilt the simulation clips the law's setpoint to (rad)
PX_TMAX, PX_MAX_TILT = 80, 81
PX4_SIZE = 82

# ---- state ----------------------------------------------------------------------------------------------------------
# the setpoint: attitude quaternion (w, x, y, z; model frame), collective thrust (N); the attitude P's rate
# setpoint (rad/s, model body FLU); the plant steps taken
PS_Q_SP, PS_THRUST_SP, PS_RATE_SP, PS_K = 0, 4, 5, 8
# rate PID: integrators (3), the previous filtered gyro (3) and whether there is one, the allocator's saturation
# feedback per axis (1.0: positive / negative torque unallocated)
PS_INTEG, PS_PREV_W, PS_HAVE_PREV, PS_SAT_POS, PS_SAT_NEG = 9, 12, 15, 16, 19
# the low passes' delay lines: d1 of the three axes, then d2 (6 each)
PS_GYRO_D, PS_DGYRO_D = 22, 28
# the motors' thrusts and commanded thrusts (N), the allocator's scratch (normalized commands); the rate-loop
# periods whose allocation left some torque unallocated (a diagnostic: the inner loops' saturation)
PS_F, PS_CMD, PS_U, PS_N_SATURATED = 34, 38, 42, 46
PX4_STATE = 47


# ---- Python side -----------------------------------------------------------------------------------------------------
def px4_constants(vehicle: Any, plant_dt: float, max_tilt: float) -> np.ndarray:
    """The attitude path's constants for the TRUE ``vehicle`` and the plant step ``plant_dt`` (s): read from the
    scalar path's own ``Px4AttitudePath`` (PX4's parameters for that vehicle as the emulator applies them), so the
    two cannot drift apart; ``max_tilt`` (rad) the setpoint's tilt clip (the sweep passes ``MappingConfig().max_tilt``,
    as ``sim.run`` clips it)."""
    from sim_bridge.inner.px4_attitude_path import Px4AttitudePath

    path = Px4AttitudePath(vehicle, plant_dt)
    att, rate, alloc, motors = path.att, path.rate, path.alloc, path.motors
    if alloc.n != 4:
        raise ValueError(f"the compiled PX4 path flies four rotors, not {alloc.n}")
    values: dict[int, float] = {PX_YAW_WEIGHT: att.yaw_weight, PX_RATE_DT: rate.dt}
    for i in range(3):
        values.update({PX_ATT_GAIN + i: att.gain[i], PX_RATE_LIMIT + i: att.rate_limit[i], PX_KP + i: rate.kp[i]})
        values.update({PX_KI + i: rate.ki[i], PX_KD + i: rate.kd[i], PX_KFF + i: rate.kff[i]})
        values.update({PX_INT_LIM + i: rate.int_lim[i]})
    values[PX_INV_400DEG] = 1.0 / math.radians(400.0)  # px4_inner's _INV_400DEG, the same expression
    for base, filters in ((PX_GYRO_LP, rate.gyro_lp), (PX_DGYRO_LP, rate.dgyro_lp)):
        values.update(_lowpass_constants(base, filters))
    values[PX_AIRMODE] = alloc.airmode
    for j in range(4):
        values.update({PX_M_ROLL + j: alloc.m_roll[j], PX_M_PITCH + j: alloc.m_pitch[j], PX_M_YAW + j: alloc.m_yaw[j]})
        values.update({PX_M_THRUST + j: alloc.m_thrust[j], PX_SPIN + j: motors.spin[j]})
        values.update({PX_EFF + 4 * a + j: alloc.eff_norm[a][j] for a in range(3)})
        values.update({PX_POS_X + j: motors.pos[j][0], PX_POS_Y + j: motors.pos[j][1]})
    values.update({PX_FMAX: motors.fmax, PX_CQ: motors.c, PX_ALPHA: motors.alpha, PX_TMAX: path.tmax})
    values[PX_MAX_TILT] = max_tilt
    return pack_constants(PX4_SIZE, values)


def _lowpass_constants(base: int, filters: list[Any]) -> dict[int, float]:
    """One ``LP_*`` block from the three axes' ``px4_inner.LowPass2`` (designed alike: one set of coefficients)."""
    f = filters[0]
    design = [(g.on, *((g.b0, g.b1, g.b2, g.a1, g.a2) if g.on else ())) for g in filters]
    if design.count(design[0]) != len(design):
        raise ValueError("the compiled PX4 rate loop takes one low pass for the three axes")
    if not f.on:  # a cutoff at or above Nyquist: the filter passes its input through
        return {base + k: 0.0 for k in range(6)}
    coefficients = {LP_ON: 1.0, LP_B0: f.b0, LP_B1: f.b1, LP_B2: f.b2, LP_A1: f.a1, LP_A2: f.a2}
    return {base + k: v for k, v in coefficients.items()}


def px4_state(thrust_each: float) -> np.ndarray:
    """The path's state after ``Px4AttitudePath.reset(thrust_each)`` on a fresh path: the motors at ``thrust_each``
    (N) each, a level setpoint at zero thrust, the integrators, filters and saturation feedback cleared."""
    s = np.zeros(PX4_STATE)
    s[PS_Q_SP] = 1.0
    s[PS_F : PS_F + 4] = thrust_each
    s[PS_CMD : PS_CMD + 4] = thrust_each
    return s


# ---- quaternions (model frame, w x y z): the scalar path's own functions, compiled as they are ----------------------
euler_to_quaternion = inline_kernel(frames.euler_to_quaternion)
_mul = inline_kernel(rotations.quat_mul)
_conj = inline_kernel(rotations.quat_conj)
_canonical = inline_kernel(px4_inner.canonical)
_body_z = inline_kernel(px4_inner.body_z)
_shortest_rotation = inline_kernel(px4_inner.shortest_rotation)


# ---- attitude P (Px4AttitudeControl.update) -----------------------------------------------------------------------
@pure_kernel
def _attitude(c: np.ndarray, s: np.ndarray, x: np.ndarray) -> None:
    """The rate setpoint (rad/s, model body FLU) for the plant's attitude ``x[6:9]`` and the setpoint quaternion:
    the thrust axis first, the yaw part of the error weighted, each axis within its rate limit; into ``s``."""
    q = euler_to_quaternion(x[6], x[7], x[8])
    qd = (s[PS_Q_SP], s[PS_Q_SP + 1], s[PS_Q_SP + 2], s[PS_Q_SP + 3])
    qd_red = _shortest_rotation(_body_z(q), _body_z(qd))
    # with the thrust axis reversed, full attitude control gives the right answer directly
    reversed_axis = abs(qd_red[1]) > 1.0 - 1e-5 or abs(qd_red[2]) > 1.0 - 1e-5
    qd_red = qd if reversed_axis else _mul(qd_red, q)
    q_mix = _canonical(_mul(_conj(qd_red), qd))  # the rest of the rotation: about the body z axis
    w = py_min(py_max(q_mix[0], -1.0), 1.0)
    zc = py_min(py_max(q_mix[3], -1.0), 1.0)
    yw = c[PX_YAW_WEIGHT]
    qd_w = _mul(qd_red, (math.cos(yw * math.acos(w)), 0.0, 0.0, math.sin(yw * math.asin(zc))))
    qe = _canonical(_mul(_conj(q), qd_w))
    for i in range(3):
        r = 2.0 * qe[i + 1] * c[PX_ATT_GAIN + i]
        lim = c[PX_RATE_LIMIT + i]
        s[PS_RATE_SP + i] = py_min(py_max(r, -lim), lim)


# ---- rate PID (Px4RateControl.update, not landed) --------------------------------------------------------------------
@inline_kernel
def _lowpass(c: np.ndarray, lp: int, s: np.ndarray, d: int, axis: int, x: float) -> float:
    """``px4_inner.LowPass2`` of one axis: constants at ``c[lp:]``, delay line ``s[d + axis]`` (d1) and
    ``s[d + 3 + axis]`` (d2); the filtered value of ``x`` (``x`` itself when the filter is off)."""
    if c[lp + LP_ON] == 0.0:
        return x
    d1, d2 = s[d + axis], s[d + 3 + axis]
    d0 = x - d1 * c[lp + LP_A1] - d2 * c[lp + LP_A2]
    y = d0 * c[lp + LP_B0] + d1 * c[lp + LP_B1] + d2 * c[lp + LP_B2]
    s[d + 3 + axis] = d1
    s[d + axis] = d0
    return y


@pure_kernel
def _rate_axis(c: np.ndarray, s: np.ndarray, i: int, rate_sp: float, gyro: float) -> float:
    """One axis of the rate PID (FRD): the normalized torque from the setpoint and the raw gyro (rad/s), D on the
    filtered gyro's low-passed derivative; the integrator then advanced (frozen in a direction the allocator
    reported saturated, reduced for large errors, limited)."""
    w = _lowpass(c, PX_GYRO_LP, s, PS_GYRO_D, i, gyro)
    if s[PS_HAVE_PREV] == 0.0:  # the first period: no derivative yet, its filter started at rest
        s[PS_PREV_W + i] = w
        if c[PX_DGYRO_LP + LP_ON] != 0.0:
            d0 = 0.0 / (c[PX_DGYRO_LP + LP_B0] + c[PX_DGYRO_LP + LP_B1] + c[PX_DGYRO_LP + LP_B2])
            s[PS_DGYRO_D + i] = s[PS_DGYRO_D + 3 + i] = d0
    acc = _lowpass(c, PX_DGYRO_LP, s, PS_DGYRO_D, i, (w - s[PS_PREV_W + i]) * (1.0 / c[PX_RATE_DT]))
    s[PS_PREV_W + i] = w
    integ = s[PS_INTEG + i]
    e = rate_sp - w
    out = c[PX_KP + i] * e + integ - c[PX_KD + i] * acc + c[PX_KFF + i] * rate_sp
    if (s[PS_SAT_POS + i] != 0.0 and e > 0.0) or (s[PS_SAT_NEG + i] != 0.0 and e < 0.0):
        e = 0.0
    f = e * c[PX_INV_400DEG]
    f = 1.0 - f * f  # less integration for large errors (no bounce-back after a flip)
    if f > 0.0:
        v = integ + f * c[PX_KI + i] * e * c[PX_RATE_DT]
        lim = c[PX_INT_LIM + i]
        s[PS_INTEG + i] = lim if v > lim else (-lim if v < -lim else v)
    return out


@inline_kernel
def _rates(c: np.ndarray, s: np.ndarray, x: np.ndarray) -> tuple:
    """The rate PID's normalized torque (FRD) for the rate setpoint and the plant's body rates (the gyro)."""
    p, q, r = body_rates(x[6], x[7], x[9], x[10], x[11])  # FLU; FRD is (p, -q, -r)
    t0 = _rate_axis(c, s, 0, s[PS_RATE_SP], p)
    t1 = _rate_axis(c, s, 1, -s[PS_RATE_SP + 1], -q)
    t2 = _rate_axis(c, s, 2, -s[PS_RATE_SP + 2], -r)
    s[PS_HAVE_PREV] = 1.0
    return t0, t1, t2


# ---- the allocator (Px4Allocator.allocate and its saturation feedback) --------------------------------------------
#: the multiple of a column that reduces the saturation the most: the scalar allocator's own function, compiled
_desaturation_gain = inline_kernel(px4_inner.desaturation_gain)


@pure_kernel
def _desaturate(c: np.ndarray, vec: int, u: np.ndarray, lo: float, hi: float, reduce_only: bool) -> None:
    """``Px4Allocator._desaturate``: ``u`` moved along the column ``c[vec:vec + 4]`` into [lo, hi] (a full step, then
    a half step that balances the rest; with ``reduce_only`` the first step only lowers)."""
    u_min, u_max = u[0], u[0]
    for i in range(1, 4):  # Python's min(u), max(u)
        u_min, u_max = py_min(u_min, u[i]), py_max(u_max, u[i])
    if u_min >= lo and u_max <= hi:
        return
    g = _desaturation_gain(c[vec : vec + 4], u, lo, hi)
    if reduce_only and g > 0.0:
        return
    for i in range(4):
        u[i] += g * c[vec + i]
    g = 0.5 * _desaturation_gain(c[vec : vec + 4], u, lo, hi)
    for i in range(4):
        u[i] += g * c[vec + i]


@inline_kernel
def _unallocated(s: np.ndarray, i: int, un: float) -> bool:
    """The saturation feedback of axis ``i`` from its unallocated normalized torque ``un``; whether there is some."""
    s[PS_SAT_POS + i] = 1.0 if un > 1e-6 else 0.0
    s[PS_SAT_NEG + i] = 1.0 if un < -1e-6 else 0.0
    return un > 1e-6 or un < -1e-6


@pure_kernel
def _allocate(c: np.ndarray, s: np.ndarray, torque: tuple, thrust: float) -> None:
    """The motor commands for the normalized torque (FRD) and thrust (0..1), desaturated per MC_AIRMODE, into the
    motors' commanded thrusts (``Px4Motors.command``); the axes left unallocated into the saturation feedback."""
    r, p, y = torque
    u = s[PS_U : PS_U + 4]
    for i in range(4):
        u[i] = c[PX_M_ROLL + i] * r + c[PX_M_PITCH + i] * p + c[PX_M_THRUST + i] * thrust
    airmode = c[PX_AIRMODE]
    if airmode == 0.0:
        _desaturate(c, PX_M_THRUST, u, 0.0, 1.0, True)
        _desaturate(c, PX_M_ROLL, u, 0.0, 1.0, False)
        _desaturate(c, PX_M_PITCH, u, 0.0, 1.0, False)
    else:  # airmode: the collective moves both ways to keep the torque
        _desaturate(c, PX_M_THRUST, u, 0.0, 1.0, False)
    for i in range(4):
        u[i] += c[PX_M_YAW + i] * y
    if airmode == 2.0:
        _desaturate(c, PX_M_THRUST, u, 0.0, 1.0, False)
        _desaturate(c, PX_M_YAW, u, 0.0, 1.0, False)
    else:
        _desaturate(c, PX_M_YAW, u, 0.0, 1.15, False)  # some yaw even at full thrust
        _desaturate(c, PX_M_THRUST, u, 0.0, 1.0, True)
    gr = gp = gy = 0.0
    for i in range(4):
        o = 0.0 if u[i] < 0.0 else (1.0 if u[i] > 1.0 else u[i])
        gr += c[PX_EFF + i] * o
        gp += c[PX_EFF + 4 + i] * o
        gy += c[PX_EFF + 8 + i] * o
        s[PS_CMD + i] = py_min(py_max(o, 0.0), 1.0) * c[PX_FMAX]
    # what the motors cannot deliver freezes the rate integrator in that direction (allocate_with_saturation_feedback)
    sat_r = _unallocated(s, 0, r - gr)
    sat_p = _unallocated(s, 1, p - gp)
    sat_y = _unallocated(s, 2, y - gy)
    if sat_r or sat_p or sat_y:
        s[PS_N_SATURATED] += 1.0


# ---- the motors (Px4Motors) and the path ---------------------------------------------------------------------------
@inline_kernel
def _motors_step(c: np.ndarray, s: np.ndarray, u: np.ndarray) -> None:
    """One plant step of the motors' lag toward their commands, then their wrench into ``u[0:4]`` (thrust N,
    torques N m body FLU)."""
    t = rx = ry = rz = 0.0
    for i in range(4):
        f = s[PS_F + i] + (s[PS_CMD + i] - s[PS_F + i]) * c[PX_ALPHA]
        s[PS_F + i] = f
        t += f
        rx -= c[PX_POS_Y + i] * f  # thrust up (-z FRD) at y right rolls left
        ry += c[PX_POS_X + i] * f  # at x forward pitches up
        rz += c[PX_SPIN + i] * c[PX_CQ] * f
    u[0], u[1], u[2], u[3] = t, rx, -ry, -rz


@pure_kernel
def px4_set_setpoint(c: np.ndarray, s: np.ndarray, phi: float, theta: float, psi: float, thrust: float) -> None:
    """The law's attitude setpoint (model-frame ZYX angles, rad) and collective thrust (N), as ``sim.run`` gives
    them to ``Px4AttitudePath.set_setpoint``: roll and pitch clipped to the mapping's tilt, the thrust to
    [0, thrust_max] (0 when not finite)."""
    tilt = c[PX_MAX_TILT]
    q = euler_to_quaternion(py_min(py_max(phi, -tilt), tilt), py_min(py_max(theta, -tilt), tilt), psi)
    s[PS_Q_SP], s[PS_Q_SP + 1], s[PS_Q_SP + 2], s[PS_Q_SP + 3] = q
    s[PS_THRUST_SP] = py_min(py_max(thrust, 0.0), c[PX_TMAX]) if math.isfinite(thrust) else 0.0


@pure_kernel
def px4_step(c: np.ndarray, s: np.ndarray, x: np.ndarray, u: np.ndarray) -> None:
    """One plant step from the plant state ``x`` (``Px4AttitudePath.step``): attitude P on every fourth step, rate
    PID and allocator on every second (from the first), the motors' lag on every one; their wrench over the step
    into ``u[0:4]`` (thrust N, torques N m body FLU)."""
    k = int(s[PS_K])
    s[PS_K] = k + 1
    if k & 3 == 0:  # attitude P at 250 Hz on a 1 kHz plant
        _attitude(c, s, x)
    if k & 1 == 0:  # rate PID and allocator at 500 Hz
        _allocate(c, s, _rates(c, s, x), s[PS_THRUST_SP] / c[PX_TMAX])
    _motors_step(c, s, u)
