"""PX4's multicopter inner loops, modelled on their structure (PX4-Autopilot main, read, not copied):

- ``Px4AttitudeControl`` (mc_att_control / AttitudeControl): quaternion P control with the reduced attitude
  (the thrust axis first), the yaw part of the error weighted by MC_YAW_WEIGHT (the yaw gain divided by the
  weight so a pure yaw error keeps MC_YAW_P), the yaw-rate feed-forward about the world vertical, rate limits
  MC_*RATE_MAX.
- ``Px4RateControl`` (mc_rate_control / RateControl): PID on the filtered gyro (IMU_GYRO_CUTOFF, 2-pole low pass),
  D on the measurement (its derivative low-passed at IMU_DGYRO_CUTOFF), feed-forward on the setpoint, gains
  multiplied by MC_*RATE_K, integrator limited to MC_*_INT_LIM, its gain reduced for large errors, frozen in the
  direction the allocator reports saturated, not run on the ground. Output: normalized torque (FRD).
- ``Px4Allocator`` (control_allocator, CA_METHOD 2 sequential desaturation): effectiveness from the CA_ROTOR*
  geometry (positions, CT, KM), pseudo-inverse, normalized as PX4 does (same scale on roll and pitch so a unit
  command is the largest symmetric one, yaw column to a largest entry of 1, each motor's thrust share 1), then
  desaturation per MC_AIRMODE (0: thrust only lowered; 1: roll / pitch airmode; 2: roll / pitch / yaw airmode),
  yaw mixed last with 15 % headroom above full and reduced to fit. Motor commands 0..1.
- ``Px4Motors``: SIH-like actuators: thrust = command x motor_thrust_max after a first-order lag
  (motor_time_constant), at the vehicle's physical rotor positions; reaction torque = yaw_moment_coefficient x
  thrust, with the spin direction of each rotor's KM sign.

Frames: this module works in PX4's body FRD for torques and rates (it is PX4's side of the wire); the caller
converts to and from the plant's FLU with ``estimators.model.frames``. Units: rad, rad/s; torques normalized (PX4) or
N m (``Px4Motors.wrench_frd``); motor commands 0..1.

Why over 500 lines: the four stages are one chain that feeds back on itself (the allocator's saturation freezes the
rate integrator, ``allocate_with_saturation_feedback``) and that three callers assemble from the same parameters
(``configure_px4_loops``): the emulator's PX4 flavour, ``Px4AttitudePath`` and ``Px4ActuatorPath``. Split, each
stage's file would import the others' internals.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from estimators.model.frames import frd_to_model_body, model_body_to_frd
from estimators.model.rotations import Quat, quat_conj, quat_mul
from estimators.model.vehicle import Vehicle


# ------------------------------------------------------------------------------------------------ quaternions
def canonical(q: Quat) -> Quat:
    """The one of q, -q with a non-negative scalar part (the shorter rotation)."""
    return q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def body_z(q: Quat) -> tuple[float, float, float]:
    """Third column of the rotation matrix of q (the body z axis in the world frame)."""
    w, x, y, z = q
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


def shortest_rotation(a: tuple[float, float, float], b: tuple[float, float, float]) -> Quat:
    """Unit quaternion of the smallest rotation taking unit vector a onto unit vector b (half-way construction)."""
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    w = d + 1.0
    n = math.sqrt(w * w + cx * cx + cy * cy + cz * cz)
    if n < 1e-9:  # opposite vectors: any half turn about an axis perpendicular to a
        return (0.0, 1.0, 0.0, 0.0) if abs(a[0]) < 0.9 else (0.0, 0.0, 1.0, 0.0)
    return (w / n, cx / n, cy / n, cz / n)


# ------------------------------------------------------------------------------------------------ attitude
class Px4AttitudeControl:
    """Attitude setpoint -> body-rate setpoint (rad/s), PX4's reduced-attitude quaternion P controller.

    Quaternions rotate body to world and may be given in any right-handed pair of frames (the plant's FLU / NWU
    or PX4's FRD / NED) as long as the attitude and its setpoint share them; rates come out in that body frame.
    """

    def __init__(self) -> None:
        self.gain = [4.0, 4.0, 2.8 / 0.4]
        self.yaw_weight = 0.4
        self.rate_limit = [math.radians(220.0), math.radians(220.0), math.radians(200.0)]

    def set_gains(self, roll_p: float, pitch_p: float, yaw_p: float, yaw_weight: float) -> None:
        """MC_ROLL_P, MC_PITCH_P, MC_YAW_P (rad/s per rad), MC_YAW_WEIGHT (0..1)."""
        self.yaw_weight = min(max(yaw_weight, 0.0), 1.0)
        # the weight scales the yaw output down; the gain is divided by it so MC_YAW_P holds for a pure yaw error
        self.gain = [roll_p, pitch_p, yaw_p / self.yaw_weight if self.yaw_weight > 1e-4 else yaw_p]

    def update(self, q: Quat, qd: Quat, yaw_rate_ff: float = 0.0) -> tuple[float, float, float]:
        """Rate setpoint for attitude ``q`` and setpoint ``qd``; ``yaw_rate_ff`` about the world vertical."""
        ez, ezd = body_z(q), body_z(qd)
        qd_red = shortest_rotation(ez, ezd)
        # the attitude that only tilts the thrust axis onto the setpoint's (with the thrust axis reversed, full
        # attitude control gives the right answer directly)
        reversed_axis = abs(qd_red[1]) > 1.0 - 1e-5 or abs(qd_red[2]) > 1.0 - 1e-5
        qd_red = qd if reversed_axis else quat_mul(qd_red, q)
        q_mix = canonical(quat_mul(quat_conj(qd_red), qd))  # the remaining rotation: about the body z axis
        w = min(max(q_mix[0], -1.0), 1.0)
        zc = min(max(q_mix[3], -1.0), 1.0)
        yw = self.yaw_weight
        qd_w = quat_mul(qd_red, (math.cos(yw * math.acos(w)), 0.0, 0.0, math.sin(yw * math.asin(zc))))
        qe = canonical(quat_mul(quat_conj(q), qd_w))
        g = self.gain
        r = [2.0 * qe[1] * g[0], 2.0 * qe[2] * g[1], 2.0 * qe[3] * g[2]]
        if yaw_rate_ff != 0.0:
            wz = body_z(quat_conj(q))  # the world z axis seen from the body
            r[0] += wz[0] * yaw_rate_ff
            r[1] += wz[1] * yaw_rate_ff
            r[2] += wz[2] * yaw_rate_ff
        lim = self.rate_limit
        return (
            min(max(r[0], -lim[0]), lim[0]),
            min(max(r[1], -lim[1]), lim[1]),
            min(max(r[2], -lim[2]), lim[2]),
        )


# ------------------------------------------------------------------------------------------------ filters
class LowPass2:
    """Two-pole Butterworth low pass (bilinear transform), one channel; cutoff <= 0 passes the input through."""

    def __init__(self, sample_hz: float, cutoff_hz: float) -> None:
        self.set(sample_hz, cutoff_hz)

    def set(self, sample_hz: float, cutoff_hz: float) -> None:
        self.on = 0.0 < cutoff_hz < 0.5 * sample_hz
        if not self.on:
            return
        fr = sample_hz / cutoff_hz
        ohm = math.tan(math.pi / fr)
        c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
        self.b0 = ohm * ohm / c
        self.b1 = 2.0 * self.b0
        self.b2 = self.b0
        self.a1 = 2.0 * (ohm * ohm - 1.0) / c
        self.a2 = (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c
        self.d1 = self.d2 = 0.0

    def reset(self, value: float) -> None:
        if self.on:
            self.d1 = self.d2 = value / (self.b0 + self.b1 + self.b2)

    def __call__(self, x: float) -> float:
        if not self.on:
            return x
        d0 = x - self.d1 * self.a1 - self.d2 * self.a2
        y = d0 * self.b0 + self.d1 * self.b1 + self.d2 * self.b2
        self.d2 = self.d1
        self.d1 = d0
        return y


# ------------------------------------------------------------------------------------------------ rates
@dataclass
class Px4RateGains:
    """MC_*RATE_P / I / D / FF (normalized torque per rad/s), MC_*RATE_K, MC_*_INT_LIM; roll, pitch, yaw."""

    p: tuple[float, float, float] = (0.15, 0.15, 0.2)
    i: tuple[float, float, float] = (0.2, 0.2, 0.1)
    d: tuple[float, float, float] = (0.003, 0.003, 0.0)
    ff: tuple[float, float, float] = (0.0, 0.0, 0.0)
    k: tuple[float, float, float] = (1.0, 1.0, 1.0)
    int_lim: tuple[float, float, float] = (0.3, 0.3, 0.3)


class Px4RateControl:
    """Body-rate setpoint + gyro (rad/s, FRD) -> normalized torque setpoint (FRD), PX4's rate PID."""

    def __init__(self, rate_hz: float, gyro_cutoff_hz: float = 40.0, dgyro_cutoff_hz: float = 20.0) -> None:
        self.dt = 1.0 / rate_hz
        self.rate_hz = rate_hz
        self.gyro_lp = [LowPass2(rate_hz, gyro_cutoff_hz) for _ in range(3)]
        self.dgyro_lp = [LowPass2(rate_hz, dgyro_cutoff_hz) for _ in range(3)]
        self.set_gains(Px4RateGains())
        self.integ = [0.0, 0.0, 0.0]
        self.prev_w: list[float] | None = None
        self.sat_pos = [False, False, False]
        self.sat_neg = [False, False, False]
        self.rate_filtered = (0.0, 0.0, 0.0)

    def set_gains(self, g: Px4RateGains) -> None:
        self.kp = [g.k[i] * g.p[i] for i in range(3)]
        self.ki = [g.k[i] * g.i[i] for i in range(3)]
        self.kd = [g.k[i] * g.d[i] for i in range(3)]
        self.kff = [g.k[i] * g.ff[i] for i in range(3)]
        self.int_lim = list(g.int_lim)

    def set_filters(self, gyro_cutoff_hz: float, dgyro_cutoff_hz: float) -> None:
        for f in self.gyro_lp:
            f.set(self.rate_hz, gyro_cutoff_hz)
        for f in self.dgyro_lp:
            f.set(self.rate_hz, dgyro_cutoff_hz)
        self.prev_w = None

    def reset_integral(self) -> None:
        self.integ = [0.0, 0.0, 0.0]

    def update(
        self, rate_sp: tuple[float, float, float], gyro: tuple[float, float, float], landed: bool
    ) -> tuple[float, float, float]:
        """One rate-loop period: normalized torque (FRD; the allocator's unit torque per axis)."""
        glp, dlp = self.gyro_lp, self.dgyro_lp
        w = (glp[0](gyro[0]), glp[1](gyro[1]), glp[2](gyro[2]))
        prev = self.prev_w
        if prev is None:
            prev = w
            for f in dlp:
                f.reset(0.0)
        inv = 1.0 / self.dt
        acc = (dlp[0]((w[0] - prev[0]) * inv), dlp[1]((w[1] - prev[1]) * inv), dlp[2]((w[2] - prev[2]) * inv))
        self.prev_w = w  # type: ignore[assignment]
        self.rate_filtered = w
        kp, ki, kd, kff, integ = self.kp, self.ki, self.kd, self.kff, self.integ
        out = [0.0, 0.0, 0.0]
        for i in range(3):
            e = rate_sp[i] - w[i]
            out[i] = kp[i] * e + integ[i] - kd[i] * acc[i] + kff[i] * rate_sp[i]
            if not landed:
                if (self.sat_pos[i] and e > 0.0) or (self.sat_neg[i] and e < 0.0):
                    e = 0.0
                f = e * _INV_400DEG
                f = 1.0 - f * f  # less integration for large errors (no bounce-back after a flip)
                if f > 0.0:
                    v = integ[i] + f * ki[i] * e * self.dt
                    lim = self.int_lim[i]
                    integ[i] = lim if v > lim else (-lim if v < -lim else v)
        return (out[0], out[1], out[2])


_INV_400DEG = 1.0 / math.radians(400.0)


# ------------------------------------------------------------------------------------------------ allocation
@dataclass(frozen=True)
class Rotor:
    """One CA_ROTORn: position (m or normalized, FRD x forward, y right), thrust coefficient CT, moment ratio KM
    (its sign is the spin direction: positive gives a positive FRD yaw torque)."""

    px: float
    py: float
    ct: float = 6.5
    km: float = 0.05


#: PX4's quadrotor X numbering as in SIH's airframe 10040 (CA_ROTOR0..3_PX/PY/KM).
QUAD_X = (Rotor(1.0, 1.0), Rotor(-1.0, -1.0), Rotor(1.0, -1.0, km=-0.05), Rotor(-1.0, 1.0, km=-0.05))
#: A quadrotor "+": right, left (same spin), front, back (the other spin), normalized positions.
QUAD_PLUS = (Rotor(0.0, 1.0), Rotor(0.0, -1.0), Rotor(1.0, 0.0, km=-0.05), Rotor(-1.0, 0.0, km=-0.05))


def quad_rotors(frame: str) -> tuple[Rotor, ...]:
    """The CA_ROTOR* geometry of a vehicle's frame (``"x"`` or ``"+"``, ``estimators.model.vehicle.FRAMES``)."""
    return QUAD_PLUS if frame == "+" else QUAD_X


def desaturation_gain(vec: Sequence[float], u: Sequence[float], lo: float, hi: float) -> float:
    """The multiple of ``vec`` to add to the motor commands ``u`` (normalized, one per motor) that reduces their
    saturation outside [lo, hi] the most (PX4's desaturation gain). Plain float arithmetic on sequences: the compiled
    PX4 loops (``sim_bridge.inner.compiled.px4_loops``) compile this very function."""
    kmin = kmax = 0.0
    for i in range(len(u)):
        v = vec[i]
        if abs(v) < 1e-7:
            continue
        if u[i] < lo:
            k = (lo - u[i]) / v
            kmin, kmax = min(kmin, k), max(kmax, k)
        if u[i] > hi:
            k = (hi - u[i]) / v
            kmin, kmax = min(kmin, k), max(kmax, k)
    return kmin + kmax


class Px4Allocator:
    """Normalized torque (FRD) + collective thrust 0..1 -> motor commands 0..1 (PX4's sequential desaturation)."""

    def __init__(self, rotors: tuple[Rotor, ...] = QUAD_X, airmode: int = 0) -> None:
        self.airmode = airmode
        self.set_rotors(rotors)
        self.unallocated = (0.0, 0.0, 0.0)

    def set_rotors(self, rotors: tuple[Rotor, ...]) -> None:
        self.rotors = rotors
        n = len(rotors)
        eff = np.zeros((6, n))
        for j, r in enumerate(rotors):
            # thrust along body -z (FRD); moment = CT p x axis - CT KM axis
            ax = np.array([0.0, 0.0, -1.0])
            p = np.array([r.px, r.py, 0.0])
            eff[0:3, j] = r.ct * np.cross(p, ax) - r.ct * r.km * ax
            eff[3:6, j] = r.ct * ax
        self.effectiveness = eff
        mix = np.linalg.pinv(eff)  # n x 6
        # PX4's normalization: roll and pitch share one scale (sqrt(|col|^2 / (non-zero / 2))), yaw to max 1,
        # thrust so each motor's share is 1
        nz_r = max(int(np.sum(np.abs(mix[:, 0]) > 1e-3)), 1)
        nz_p = max(int(np.sum(np.abs(mix[:, 1]) > 1e-3)), 1)
        s_rp = max(
            math.sqrt(float(mix[:, 0] @ mix[:, 0]) / (nz_r / 2.0)),
            math.sqrt(float(mix[:, 1] @ mix[:, 1]) / (nz_p / 2.0)),
        )
        s_y = float(np.max(mix[:, 2])) or 1.0
        col_t = np.abs(mix[:, 5])
        s_t = float(np.sum(col_t) / max(int(np.sum(col_t > 1e-6)), 1)) or 1.0
        self.scale = (s_rp, s_rp, s_y, s_t)
        # rounded to 1e-9 so a symmetric airframe gets exactly symmetric columns (the pseudo-inverse leaves 1e-14
        # differences, which would turn a pure thrust command into a tiny torque)
        self.m_roll = [round(float(v) / s_rp, 9) for v in mix[:, 0]]
        self.m_pitch = [round(float(v) / s_rp, 9) for v in mix[:, 1]]
        self.m_yaw = [round(float(v) / s_y, 9) for v in mix[:, 2]]
        self.m_thrust = [round(float(-v) / s_t, 9) for v in mix[:, 5]]  # per unit of upward (positive) collective
        # the torque one set of motor commands gives, in the normalized units (for the saturation report)
        en = eff[0:3, :] * np.array([s_rp, s_rp, s_y])[:, None]
        self.eff_norm = [[float(v) for v in row] for row in en]
        self.n = n

    def _desaturate(self, u: list[float], vec: list[float], lo: float, hi: float, reduce_only: bool = False) -> None:
        if min(u) >= lo and max(u) <= hi:  # nothing saturated (the common case): nothing to do
            return
        g = desaturation_gain(vec, u, lo, hi)
        if reduce_only and g > 0.0:  # thrust may only be lowered (the vector points up)
            return
        for i in range(self.n):
            u[i] += g * vec[i]
        # a second, half step balances the remaining saturation; like PX4's desaturateActuators it is taken in
        # either direction (only the first step is one-sided): returning here left "full thrust + large roll" at
        # all motors 0 (the roll step then had to undo twice the overshoot)
        g = 0.5 * desaturation_gain(vec, u, lo, hi)
        for i in range(self.n):
            u[i] += g * vec[i]

    def allocate(self, torque: tuple[float, float, float], thrust: float) -> list[float]:
        """Motor commands 0..1 for normalized torque (FRD) and collective thrust (0..1, upward)."""
        n = self.n
        r, p, y = torque
        mr, mp, my, mt = self.m_roll, self.m_pitch, self.m_yaw, self.m_thrust
        u = [mr[i] * r + mp[i] * p + mt[i] * thrust for i in range(n)]
        if self.airmode == 0:
            self._desaturate(u, mt, 0.0, 1.0, reduce_only=True)
            self._desaturate(u, mr, 0.0, 1.0)
            self._desaturate(u, mp, 0.0, 1.0)
        else:
            self._desaturate(u, mt, 0.0, 1.0)  # airmode: the collective moves both ways to keep the torque
        if self.airmode == 2:
            for i in range(n):
                u[i] += my[i] * y
            self._desaturate(u, mt, 0.0, 1.0)
            self._desaturate(u, my, 0.0, 1.0)
        else:
            for i in range(n):
                u[i] += my[i] * y
            self._desaturate(u, my, 0.0, 1.15)  # some yaw even at full thrust
            self._desaturate(u, mt, 0.0, 1.0, reduce_only=True)
        out = [0.0 if v < 0.0 else (1.0 if v > 1.0 else v) for v in u]
        # what the motors will deliver, in normalized torque: the rest is unallocated (the rate loop's windup flag)
        er, ep, ey = self.eff_norm
        gr = gp = gy = 0.0
        for i in range(n):
            o = out[i]
            gr += er[i] * o
            gp += ep[i] * o
            gy += ey[i] * o
        self.unallocated = (r - gr, p - gp, y - gy)
        return out


# ------------------------------------------------------------------------------------------------ motors
class Px4Motors:
    """Rotors of the vehicle: command 0..1 -> thrust (N) with a first-order lag, wrench in body FRD (N, N m)."""

    def __init__(self, vehicle: Vehicle, rotors: tuple[Rotor, ...], dt: float) -> None:
        # physical positions: the rotors' directions (CA_ROTOR* may be normalized) at the vehicle's arm length
        self.pos = []
        for r in rotors:
            n = math.hypot(r.px, r.py) or 1.0
            self.pos.append((vehicle.arm_length * r.px / n, vehicle.arm_length * r.py / n))
        self.spin = [1.0 if r.km >= 0.0 else -1.0 for r in rotors]
        self.fmax = vehicle.motor_thrust_max
        self.c = vehicle.yaw_moment_coefficient
        tau = vehicle.motor_time_constant
        self.alpha = 1.0 if tau <= 0.0 else 1.0 - math.exp(-dt / tau)
        self.f = [0.0] * len(rotors)
        self.cmd = [0.0] * len(rotors)

    def command(self, u: list[float]) -> None:
        fm = self.fmax
        self.cmd = [min(max(v, 0.0), 1.0) * fm for v in u]

    def reset(self, thrust_each: float = 0.0) -> None:
        self.f = [thrust_each] * len(self.f)
        self.cmd = [thrust_each] * len(self.f)

    def step(self) -> tuple[float, float, float, float]:
        """Advance the lag one period; (collective thrust N up, roll, pitch, yaw torque N m FRD)."""
        al = self.alpha
        f, c = self.f, self.cmd
        for i in range(len(f)):
            f[i] += (c[i] - f[i]) * al
        return self.wrench_frd()

    def wrench_frd(self) -> tuple[float, float, float, float]:
        t = rx = ry = rz = 0.0
        cq = self.c
        pos, spin = self.pos, self.spin
        for i, f in enumerate(self.f):
            px, py = pos[i]
            t += f
            rx -= py * f  # thrust up (-z FRD) at y right rolls left
            ry += px * f  # at x forward pitches up
            rz += spin[i] * cq * f
        return t, rx, ry, rz


class Px4ActuatorPath:
    """What a torque command meets on PX4 behind SET_ACTUATOR_CONTROL_TARGET, for the in-process simulation
    (``slung sim --actuators px4``): physical torque (N m, FLU) divided by the allocator's unit torque, PX4's
    sequential-desaturation allocator (airmode off by default, MC_AIRMODE 0) and SIH-like motors with lag.

    Same methods as ``sim_bridge.inner.airframe.Mixer`` (allocate, wrench, step, reset), model-frame outputs
    ``(thrust N, tau_x, tau_y, tau_z N m, FLU)``. The unit torque is the motors' wrench for the allocator's unit
    roll / pitch / yaw columns (what ``offboard.flight.px4_allocation.unit_torques`` derives from CA_ROTOR*).
    """

    def __init__(self, vehicle: Vehicle, dt: float, airmode: int = 0) -> None:
        rotors = quad_rotors(vehicle.frame)
        self.alloc = Px4Allocator(rotors, airmode)
        self.motors = Px4Motors(vehicle, rotors, dt)
        self.tmax = vehicle.motor_thrust_max * len(rotors)
        unit = []
        for axis, col in enumerate((self.alloc.m_roll, self.alloc.m_pitch, self.alloc.m_yaw)):
            self.motors.f = [v * vehicle.motor_thrust_max for v in col]
            unit.append(abs(self.motors.wrench_frd()[1 + axis]))
        self.unit_torque = (unit[0], unit[1], unit[2])
        self.motors.reset(0.0)

    def reset(self, thrust_each: float = 0.0) -> None:
        self.motors.reset(thrust_each)

    def allocate(self, thrust: float, tx: float, ty: float, tz: float) -> list[float]:
        """Motor commands 0..1 for a thrust (N) and model-frame torques (N m, FLU)."""
        rx, ry, rz = model_body_to_frd(tx, ty, tz)
        ur, up, uy = self.unit_torque
        u = self.alloc.allocate((rx / ur, ry / up, rz / uy), thrust / self.tmax)
        self.motors.command(u)
        return u

    def _model(self, w: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        tx, ty, tz = frd_to_model_body(w[1], w[2], w[3])
        return w[0], tx, ty, tz

    def wrench(self) -> tuple[float, float, float, float]:
        return self._model(self.motors.wrench_frd())

    def step(self) -> tuple[float, float, float, float]:
        return self._model(self.motors.step())


def allocate_with_saturation_feedback(
    alloc: Px4Allocator, rate: Px4RateControl, torque_norm: tuple[float, float, float], thrust_norm: float
) -> list[float]:
    """PX4's allocator on a normalized torque (FRD) and thrust (0..1), and what PX4 feeds back from it: the axes and
    directions it could not allocate freeze the rate loop's integrator (``sat_pos`` / ``sat_neg``). Returns the motor
    commands 0..1."""
    u = alloc.allocate(torque_norm, thrust_norm)
    un = alloc.unallocated
    rate.sat_pos = [un[0] > 1e-6, un[1] > 1e-6, un[2] > 1e-6]
    rate.sat_neg = [un[0] < -1e-6, un[1] < -1e-6, un[2] < -1e-6]
    return u


def configure_px4_loops(
    param: Callable[[str], float],
    att: Px4AttitudeControl,
    rate: Px4RateControl,
    alloc: Px4Allocator,
    changed: str | None = None,
) -> tuple[Rotor, ...] | None:
    """Push PX4's parameters (``param(name)``: MC_*_P, MC_*RATE_*, IMU_*GYRO_CUTOFF, CA_ROTOR*, MC_AIRMODE) into its
    attitude P, rate PID and allocator, as PX4 applies them. ``changed``: the one parameter just set (None: all):
    the gyro filters are re-designed only for an IMU_ parameter, the rotors only for a CA_ one. Returns the rotors
    when they were set (the caller's motors sit at their positions), else None."""
    att.set_gains(param("MC_ROLL_P"), param("MC_PITCH_P"), param("MC_YAW_P"), param("MC_YAW_WEIGHT"))
    att.rate_limit = [math.radians(param(f"MC_{a}RATE_MAX")) for a in ("ROLL", "PITCH", "YAW")]
    axes = ("ROLL", "PITCH", "YAW")
    rate.set_gains(
        Px4RateGains(
            p=tuple(param(f"MC_{a}RATE_P") for a in axes),  # type: ignore[arg-type]
            i=tuple(param(f"MC_{a}RATE_I") for a in axes),  # type: ignore[arg-type]
            d=tuple(param(f"MC_{a}RATE_D") for a in axes),  # type: ignore[arg-type]
            ff=tuple(param(f"MC_{a}RATE_FF") for a in axes),  # type: ignore[arg-type]
            k=tuple(param(f"MC_{a}RATE_K") for a in axes),  # type: ignore[arg-type]
            int_lim=(param("MC_RR_INT_LIM"), param("MC_PR_INT_LIM"), param("MC_YR_INT_LIM")),
        )
    )
    if changed is None or changed.startswith("IMU_"):
        rate.set_filters(param("IMU_GYRO_CUTOFF"), param("IMU_DGYRO_CUTOFF"))
    rotors = None
    if changed is None or changed.startswith("CA_"):
        rotors = tuple(Rotor(*(param(f"CA_ROTOR{n}_{k}") for k in ("PX", "PY", "CT", "KM"))) for n in range(4))
        alloc.set_rotors(rotors)
    alloc.airmode = int(param("MC_AIRMODE"))
    return rotors


__all__ = [
    "QUAD_PLUS",
    "QUAD_X",
    "LowPass2",
    "Px4ActuatorPath",
    "Px4Allocator",
    "Px4AttitudeControl",
    "Px4Motors",
    "Px4RateControl",
    "Px4RateGains",
    "Rotor",
    "allocate_with_saturation_feedback",
    "configure_px4_loops",
    "quad_rotors",
]
