"""The vehicle's side of a compiled run: the plant (``sim_bridge.plant.dynamics``), its still-air drag, the cable
tension, the sensors' values (``sim_bridge.plant.sensors``), the sweep's gust and the four-motor mixer
(``sim_bridge.inner.airframe.Mixer``), each for one run, with the scalar path's expressions in its order, except
where speed asked for the same equations in other operations: the derivative multiplies by reciprocals where the
scalar path divides, and the RK4 stages take their sines and cosines by angle addition (:func:`rk4_step_trig`):
an RK4 step equals the scalar one to a few ulp, not to the bit (``tests/test_compiled_plant.py``).

State ``x`` (18,) and input ``u`` (13,) are the plant's vectors (``sim_bridge.plant.dynamics``: world NWU, SI, Euler
angles ZYX in rad, the cable's unit direction ``r`` from vehicle to load and its rate). The true vehicle's constants
are a float array indexed by the ``P_*`` constants (:func:`plant_constants`), the mixer's by ``MIX_*``
(:func:`mixer_constants`), the gust's by ``GUST_*`` (:func:`gust_constants`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators import kernels as kern
from estimators.kernels import (
    ATT,
    LOAD,
    POS,
    contracted_kernel,
    inline_kernel,
    maximum,
    minimum,
    pure_kernel,
    wrap_angle,
)
from estimators.model import cable, rotations
from sim_bridge.plant import dynamics

# ---- the true vehicle ---------------------------------------------------------------------------------------------
P_M, P_m, P_L, P_G, P_IP, P_IT, P_IS, P_KDV, P_KDW = range(9)
#: reciprocals of the masses, of their sum, of the cable's length and of the inertia: the derivative multiplies by
#: them (fourteen divisions per call were a third of an RK4 step; the results move by an ulp or so)
P_INV_M, P_INV_m, P_INV_MT, P_INV_L, P_INV_IP, P_INV_IT, P_INV_IS = range(9, 16)
PLANT_SIZE = 16


def plant_constants(vehicle: Any) -> np.ndarray:
    """A run's TRUE vehicle as the plant's constants: masses (kg), cable length (m), gravity (m/s^2), the paper
    model's inertia (kg m^2), still-air drag (N per m/s, N m per rad/s), then the reciprocals (``P_INV_*``)."""
    ip, it, i_s = vehicle.inertia
    M, m = vehicle.mass_vehicle, vehicle.mass_load
    return np.array(
        [
            vehicle.mass_vehicle,
            vehicle.mass_load,
            vehicle.cable_length,
            vehicle.gravity,
            ip,
            it,
            i_s,
            vehicle.linear_drag,
            vehicle.angular_drag,
            1.0 / M,
            1.0 / m,
            1.0 / (M + m),
            1.0 / vehicle.cable_length,
            1.0 / ip,
            1.0 / it,
            1.0 / i_s,
        ]
    )


# ---- the scalar path's own functions, compiled as they are ----------------------------------------------------------
#: the cable's projection onto ``|r| = 1``, ``r . r' = 0`` after a step, the thrust's direction in the world frame,
#: the two planar swing angles and their rates
_project_cable = inline_kernel(dynamics.project_cable)
_thrust_direction = inline_kernel(rotations.thrust_direction_trig)
_planar_swing = inline_kernel(cable.planar_swing)


# ---- the attitude's sines and cosines, shared by the kernels that read one state ------------------------------------
TRIG_SIZE = 6  # sin phi, cos phi, sin theta, cos theta, sin psi, cos psi


@pure_kernel
def angle_trig(x: np.ndarray, trig: np.ndarray) -> None:
    """The sines and cosines of the state's Euler angles ``x[6:9]`` (rad) into ``trig`` (``TRIG_SIZE``): what
    :func:`derivative`, :func:`tension` and :func:`measure` would each compute from ``x``, computed once."""
    trig[0], trig[1], trig[2], trig[3], trig[4], trig[5] = attitude_trig(x)


#: the largest angle step (rad) :func:`_shifted` takes by its series; beyond it libm (at a 1 ms step: from 60 rad/s
#: for the two half-step stages, 30 rad/s for the full-step one, a run tumbling)
_SERIES_STEP = 0.03


# the series' coefficients, products rather than divisions (a division costs as much as a dozen products)
_S3, _S5, _S7, _S9 = -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362880.0
_C2, _C4, _C6, _C8, _C10 = -0.5, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0, -1.0 / 3628800.0


@inline_kernel
def _shifted(a: float, s: float, c: float, d: float) -> tuple[float, float]:
    """``(sin(a + d), cos(a + d))`` from ``s = sin a``, ``c = cos a`` and a small step ``d`` (rad) by the angle-addition
    formulas with ``sin d`` and ``cos d`` as Taylor series (truncated after d^9 / 9! and d^10 / 10!: below 1e-22 at
    ``_SERIES_STEP``): a few ulp from libm's ``sin(a + d)``, at the cost of a dozen multiplications instead of a
    libm call. Why: the RK4 stages' attitude moves by ``h/2 * rate`` from a state whose sines are known, and these
    calls were the largest single cost of a compiled tick."""
    if not abs(d) <= _SERIES_STEP:  # (a NaN step too: libm propagates it)
        return math.sin(a + d), math.cos(a + d)
    d2 = d * d
    sd = d + d * d2 * (_S3 + d2 * (_S5 + d2 * (_S7 + d2 * _S9)))
    cd = 1.0 + d2 * (_C2 + d2 * (_C4 + d2 * (_C6 + d2 * (_C8 + d2 * _C10))))
    return s * cd + c * sd, c * cd - s * sd


@pure_kernel
def derivative(x: np.ndarray, u: np.ndarray, p: np.ndarray, out: np.ndarray) -> None:
    """``sim_bridge.plant.dynamics.derivative`` (paper attitude model, a load of mass > 0) into ``out`` (18,)."""
    derivative_at(x, u, p, attitude_trig(x), out)


@inline_kernel
def attitude_trig(x: np.ndarray) -> tuple:
    """``(sin phi, cos phi, sin theta, cos theta, sin psi, cos psi)`` of the state ``x`` from libm."""
    return math.sin(x[6]), math.cos(x[6]), math.sin(x[7]), math.cos(x[7]), math.sin(x[8]), math.cos(x[8])


@inline_kernel
def trig_of(trig: np.ndarray) -> tuple:
    """The six values of a ``trig`` array (:func:`angle_trig`) as the tuple the ``*_at`` kernels take."""
    return trig[0], trig[1], trig[2], trig[3], trig[4], trig[5]


@inline_kernel
def derivative_at(x: np.ndarray, u: np.ndarray, p: np.ndarray, sc: tuple, out: np.ndarray) -> None:
    """:func:`derivative` with ``sc`` the sines and cosines of ``x``'s attitude (:func:`attitude_trig`'s order)."""
    sf, cf, st, ct, sp, cp = sc
    r1, r2, r3 = x[12], x[13], x[14]
    d1, d2, d3 = x[15], x[16], x[17]
    M, m, l = p[P_M], p[P_m], p[P_L]
    inv_M, inv_m = p[P_INV_M], p[P_INV_m]
    thrust = u[0]
    n1, n2, n3 = _thrust_direction(sf, cf, st, ct, sp, cp)
    q1 = thrust * n1 + u[4]
    q2 = thrust * n2 + u[5]
    q3 = thrust * n3 + u[6]
    rd2 = d1 * d1 + d2 * d2 + d3 * d3
    rq = r1 * q1 + r2 * q2 + r3 * q3
    rl = r1 * u[7] + r2 * u[8] + r3 * u[9]
    T = (m * M * l * rd2 + M * rl - m * rq) * p[P_INV_MT]
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[3] = (q1 + T * r1) * inv_M
    out[4] = (q2 + T * r2) * inv_M
    out[5] = (q3 + T * r3) * inv_M - p[P_G]
    w1 = u[7] * inv_m - q1 * inv_M
    w2 = u[8] * inv_m - q2 * inv_M
    w3 = u[9] * inv_m - q3 * inv_M
    wr = w1 * r1 + w2 * r2 + w3 * r3
    inv_l = p[P_INV_L]
    out[6], out[7], out[8] = x[9], x[10], x[11]
    out[9] = (u[1] + u[10]) * p[P_INV_IP]
    out[10] = (u[2] + u[11]) * p[P_INV_IT]
    out[11] = (u[3] + u[12]) * p[P_INV_IS]
    out[12], out[13], out[14] = x[15], x[16], x[17]
    out[15] = (w1 - wr * r1) * inv_l - rd2 * r1
    out[16] = (w2 - wr * r2) * inv_l - rd2 * r2
    out[17] = (w3 - wr * r3) * inv_l - rd2 * r3


@pure_kernel
def rk4_step(x: np.ndarray, u: np.ndarray, p: np.ndarray, h: float, work: np.ndarray) -> None:
    """``sim_bridge.plant.dynamics.rk4_step`` in place on ``x`` (input held over ``h`` s, the cable projected back
    onto ``|r| = 1``, ``r . r' = 0``); ``work`` (6, 18) is scratch (its last row the attitude's sines)."""
    if work.shape[0] < 6 or work.shape[1] < 18:
        raise ValueError("rk4_step: work must be at least (6, 18)")
    trig = work[5, 0:TRIG_SIZE]
    angle_trig(x, trig)
    rk4_step_trig(x, u, p, h, work, trig)


@inline_kernel
def _stage(x: np.ndarray, k: np.ndarray, c: float, trig: np.ndarray, y: np.ndarray) -> tuple:
    """The RK4 stage state ``y = x + c k`` and the sines and cosines of its attitude (from ``trig``, ``x``'s)."""
    for i in range(18):
        y[i] = x[i] + c * k[i]
    sf, cf = _shifted(x[6], trig[0], trig[1], c * k[6])
    st, ct = _shifted(x[7], trig[2], trig[3], c * k[7])
    sp, cp = _shifted(x[8], trig[4], trig[5], c * k[8])
    return sf, cf, st, ct, sp, cp


@contracted_kernel
def rk4_step_trig(x: np.ndarray, u: np.ndarray, p: np.ndarray, h: float, work: np.ndarray, trig: np.ndarray) -> None:
    """:func:`rk4_step` with ``trig`` (``TRIG_SIZE``) the sines and cosines of ``x``'s attitude (:func:`angle_trig`),
    left as those of the new ``x``: the stages' from them by :func:`_shifted`, so a step calls libm three times
    (the new state's) instead of twelve; the caller's :func:`tension_at` and :func:`measure` read them too."""
    k1, k2, k3, k4, y = work[0], work[1], work[2], work[3], work[4]
    derivative_at(x, u, p, trig_of(trig), k1)
    hh = 0.5 * h
    derivative_at(y, u, p, _stage(x, k1, hh, trig, y), k2)
    derivative_at(y, u, p, _stage(x, k2, hh, trig, y), k3)
    derivative_at(y, u, p, _stage(x, k3, h, trig, y), k4)
    h6 = h / 6.0
    for i in range(18):
        x[i] = x[i] + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    _project_cable(x)
    angle_trig(x, trig)


@pure_kernel
def tension(x: np.ndarray, u: np.ndarray, p: np.ndarray) -> float:
    """``sim_bridge.plant.dynamics.tension``: the cable's tension, N (<= 0: slack)."""
    return tension_at(x, u, p, attitude_trig(x))


@inline_kernel
def tension_at(x: np.ndarray, u: np.ndarray, p: np.ndarray, sc: tuple) -> float:
    """:func:`tension` with ``sc`` the sines and cosines of ``x``'s attitude (:func:`attitude_trig`'s order)."""
    sf, cf, st, ct, sp, cp = sc
    n1, n2, n3 = sf * sp + cf * cp * st, cf * sp * st - cp * sf, cf * ct
    r1, r2, r3 = x[12], x[13], x[14]
    d1, d2, d3 = x[15], x[16], x[17]
    thrust = u[0]
    rq = r1 * (thrust * n1 + u[4]) + r2 * (thrust * n2 + u[5]) + r3 * (thrust * n3 + u[6])
    rl = r1 * u[7] + r2 * u[8] + r3 * u[9]
    M, m, l = p[P_M], p[P_m], p[P_L]
    return (m * M * l * (d1 * d1 + d2 * d2 + d3 * d3) + M * rl - m * rq) / (M + m)


#: (p, q, r) rad/s body FLU from the Euler angles and rates: the scalar path's own, compiled as it is
body_rates = inline_kernel(rotations.body_rates)


@pure_kernel
def apply_drag(u: np.ndarray, x: np.ndarray, force: np.ndarray, torque: np.ndarray, p: np.ndarray) -> None:
    """``sim_bridge.plant.dynamics.apply_drag``: ``u``'s external force on the vehicle (slots 4-6) and torque (10-12)
    become the disturbance's (``force`` N world, ``torque`` N m body) plus still-air drag at ``x``; a zero
    coefficient leaves its slots alone."""
    kdv, kdw = p[P_KDV], p[P_KDW]
    if kdv > 0.0:
        u[4], u[5], u[6] = force[0] - kdv * x[3], force[1] - kdv * x[4], force[2] - kdv * x[5]
    if kdw > 0.0:
        wx, wy, wz = body_rates(x[6], x[7], x[9], x[10], x[11])
        u[10], u[11], u[12] = torque[0] - kdw * wx, torque[1] - kdw * wy, torque[2] - kdw * wz


# ---- sensors --------------------------------------------------------------------------------------------------------
@pure_kernel
def measure(
    kind: int, x: np.ndarray, deriv: np.ndarray, g: float, bias: np.ndarray, e: np.ndarray, out: np.ndarray
) -> None:
    """``SensorSuite._measure``'s values of a record of ``kind`` into
    ``out``: the state ``x``, the plant derivative ``deriv`` at it (the accelerometer only), gravity ``g``, the
    accelerometer's bias (3,) and the record's noise ``e``. Fields as ``estimators.model.measurements`` after the
    time (position / velocity world NWU; attitude ZYX, body rates FLU; specific force body FLU; load angles)."""
    measure_at(kind, x, attitude_trig(x), deriv, g, bias, e, out)


@inline_kernel
def measure_at(
    kind: int, x: np.ndarray, sc: tuple, deriv: np.ndarray, g: float, bias: np.ndarray, e: np.ndarray, out: np.ndarray
) -> None:
    """:func:`measure` with ``sc`` the sines and cosines of ``x``'s attitude (:func:`attitude_trig`'s order)."""
    sf, cf, st, ct, sp, cp = sc
    if kind == POS:
        for i in range(6):
            out[i] = x[i] + e[i]
        return
    if kind == LOAD:
        r1, r2, r3 = x[12], x[13], x[14]
        out[0] = math.atan2(r2, -r3) + e[0]
        out[1] = math.atan2(r1, -r3) + e[1]
        return
    p = x[9] - st * x[11]
    q = cf * x[10] + sf * ct * x[11]
    r = -sf * x[10] + cf * ct * x[11]
    if kind == ATT:
        out[0], out[1], out[2] = x[6] + e[0], x[7] + e[1], wrap_angle(x[8] + e[2])
        out[3], out[4], out[5] = p + e[3], q + e[4], r + e[5]
        return
    fx, fy, fz = deriv[3], deriv[4], deriv[5] + g  # sim_bridge.plant.sensors.specific_force_body
    bx = cp * ct * fx + sp * ct * fy - st * fz
    by = (cp * st * sf - sp * cf) * fx + (sp * st * sf + cp * cf) * fy + ct * sf * fz
    bz = (cp * st * cf + sp * sf) * fx + (sp * st * cf - cp * sf) * fy + ct * cf * fz
    out[0], out[1], out[2] = bx + bias[0] + e[0], by + bias[1] + e[1], bz + bias[2] + e[2]
    out[3], out[4], out[5] = p + e[3], q + e[4], r + e[5]


# ---- the sweep's gust ---------------------------------------------------------------------------------------------
GUST_START, GUST_LENGTH, GUST_FORCE, GUST_COS, GUST_SIN = range(5)
GUST_SIZE = 5


def gust_constants(gust: Any) -> np.ndarray:
    """The sweep's 1 - cos gust (``offboard.harness.sweep._Gust``; None: no gust) as constants: start (s), length
    (s), peak force (N), the cosine and sine of its horizontal direction."""
    if gust is None:
        return np.array([0.0, 1.0, 0.0, 1.0, 0.0])
    return np.array([gust.start, gust.length, gust.force, math.cos(gust.direction), math.sin(gust.direction)])


@pure_kernel
def gust_at(c: np.ndarray, t: float, out: np.ndarray) -> None:
    """The gust's disturbance at ``t`` (s) into ``out`` (9,): force on the vehicle (N, world), 30 % of it on the load,
    no torque (``offboard.harness.sweep._Gust``)."""
    for i in range(9):
        out[i] = 0.0
    s = (t - c[GUST_START]) / c[GUST_LENGTH]
    force = c[GUST_FORCE]
    if not (s >= 0.0 and s <= 1.0) or force == 0.0:
        return
    w = 0.5 * (1.0 - math.cos(2.0 * math.pi * s)) * force
    out[0], out[1] = w * c[GUST_COS], w * c[GUST_SIN]
    out[3], out[4] = 0.3 * w * c[GUST_COS], 0.3 * w * c[GUST_SIN]


# ---- the mixer (sim_bridge.inner.airframe.Mixer) --------------------------------------------------------------------
MIX_A, MIX_C, MIX_FMAX, MIX_ALPHA = range(4)
MIX_SIZE = 4


def mixer_constants(vehicle: Any, dt: float) -> np.ndarray:
    """The true vehicle's X mixer: the perpendicular arm (m), the yaw moment coefficient (m), one motor's thrust
    limit (N) and the first-order motor lag's factor per plant step of ``dt`` s."""
    tau = vehicle.motor_time_constant
    alpha = 1.0 if tau <= 0.0 else 1.0 - math.exp(-dt / tau)
    a = vehicle.arm_length / math.sqrt(2.0)
    return np.array([a, vehicle.yaw_moment_coefficient, vehicle.motor_thrust_max, alpha])


@pure_kernel
def mixer_allocate(c: np.ndarray, thrust: float, tx: float, ty: float, tz: float, cmd: np.ndarray) -> None:
    """The four motors' commanded thrusts (N) into ``cmd`` for the wrench (thrust N, torques N m body FLU): roll /
    pitch first, the collective shifted to fit, yaw with what is left (``sim_bridge.inner.airframe.Mixer.allocate``)."""
    fmax, a = c[MIX_FMAX], c[MIX_A]
    base = 0.25 * (thrust if thrust < 4.0 * fmax else 4.0 * fmax)
    if base < 0.0:
        base = 0.0
    kx = tx / (4.0 * a)
    ky = ty / (4.0 * a)
    kz = tz / (4.0 * c[MIX_C])
    r0, r1, r2, r3 = kx - ky, -kx - ky, -kx + ky, kx + ky
    lo = minimum(minimum(r0, r1), minimum(r2, r3))
    hi = maximum(maximum(r0, r1), maximum(r2, r3))
    span = hi - lo
    if span > fmax:
        s = fmax / span
        r0, r1, r2, r3 = r0 * s, r1 * s, r2 * s, r3 * s
        lo, hi = lo * s, hi * s
    if base + hi > fmax:
        base = fmax - hi
    if base + lo < 0.0:
        s = base / -lo
        r0, r1, r2, r3 = r0 * s, r1 * s, r2 * s, r3 * s
    f0, f1, f2, f3 = base + r0, base + r1, base + r2, base + r3
    if kz > 0.0:
        k = minimum(minimum(1.0, (fmax - f0) / kz), minimum((fmax - f2) / kz, f1 / kz))
        k = minimum(k, f3 / kz)
    elif kz < 0.0:
        kn = -kz
        k = minimum(minimum(1.0, f0 / kn), minimum(f2 / kn, (fmax - f1) / kn))
        k = minimum(k, (fmax - f3) / kn)
    else:
        k = 1.0
    if k < 0.0:
        k = 0.0
    y = k * kz
    cmd[0], cmd[1], cmd[2], cmd[3] = f0 + y, f1 - y, f2 + y, f3 - y
    for i in range(4):
        v = cmd[i]
        cmd[i] = 0.0 if v < 0.0 else (fmax if v > fmax else v)


@pure_kernel
def mixer_wrench(c: np.ndarray, f: np.ndarray, u: np.ndarray) -> None:
    """The wrench of the motors' thrusts ``f`` (4,) into ``u[0:4]``: thrust N, torques N m body FLU."""
    f0, f1, f2, f3 = f[0], f[1], f[2], f[3]
    a = c[MIX_A]
    u[0] = f0 + f1 + f2 + f3
    u[1] = a * (f0 - f1 - f2 + f3)
    u[2] = a * (-f0 - f1 + f2 + f3)
    u[3] = c[MIX_C] * (f0 - f1 + f2 - f3)


@pure_kernel
def mixer_step(c: np.ndarray, f: np.ndarray, cmd: np.ndarray, u: np.ndarray) -> None:
    """One plant step of the motors' lag toward ``cmd``, then their wrench into ``u[0:4]``."""
    alpha = c[MIX_ALPHA]
    for i in range(4):
        f[i] = f[i] + (cmd[i] - f[i]) * alpha
    mixer_wrench(c, f, u)


# ---- the true state as the controller's input ------------------------------------------------------------------------
@pure_kernel
def truth_state(x: np.ndarray, l: float, g: float, c: float, out: np.ndarray) -> None:
    """``estimators.model.flatness.truth_control_state`` into the
    estimate vector ``out`` (``kernels.EST_*``), with the controller's nominal flat constants ``l`` (m), ``g``
    (m/s^2), ``c``."""
    truth_state_at(x, math.sin(x[8]), math.cos(x[8]), l, g, c, out)


@inline_kernel
def truth_state_at(x: np.ndarray, sp: float, cp: float, l: float, g: float, c: float, out: np.ndarray) -> None:
    """:func:`truth_state` with the sine and cosine of ``x``'s yaw given."""
    ay, ax, ayd, axd = _planar_swing(x[12], x[13], x[14], x[15], x[16], x[17])
    phi, theta, psi, dphi, dtheta, dpsi = x[6], x[7], x[8], x[9], x[10], x[11]
    nx = theta * cp + phi * sp
    ny = theta * sp - phi * cp
    nxd = dtheta * cp + dphi * sp - dpsi * ny
    nyd = dtheta * sp - dphi * cp + dpsi * nx
    out[kern.EST_FX + 0], out[kern.EST_FX + 1] = x[0] + l * ay, x[3] + l * ayd
    out[kern.EST_FX + 2], out[kern.EST_FX + 3] = -g * ay, -g * ayd
    out[kern.EST_FX + 4], out[kern.EST_FX + 5] = c * (ay + nx), c * (ayd + nxd)
    out[kern.EST_FY + 0], out[kern.EST_FY + 1] = x[1] + l * ax, x[4] + l * axd
    out[kern.EST_FY + 2], out[kern.EST_FY + 3] = -g * ax, -g * axd
    out[kern.EST_FY + 4], out[kern.EST_FY + 5] = c * (ax + ny), c * (axd + nyd)
    out[kern.EST_Z], out[kern.EST_Z_RATE] = x[2], x[5]
    out[kern.EST_PHI], out[kern.EST_THETA], out[kern.EST_PSI] = phi, theta, psi
    out[kern.EST_PHI_RATE], out[kern.EST_THETA_RATE], out[kern.EST_PSI_RATE] = dphi, dtheta, dpsi
    out[kern.EST_ALPHA_X], out[kern.EST_ALPHA_Y] = ax, ay
    out[kern.EST_ALPHA_X_RATE], out[kern.EST_ALPHA_Y_RATE] = axd, ayd
