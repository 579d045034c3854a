"""Airframe of the emulated vehicle: X-quad mixer with motor limits and lag, inner attitude / rate loops, and a
simple position / velocity controller.

Everything here works in slung's model frame (world NWU z-up, body FLU, see ``estimators/model/frames.py``); the
MAVLink boundary (``sim_bridge/autopilot.py``) converts setpoints from NED / FRD with ``estimators.model.frames`` before
they reach this module. All hot-path functions take and return plain floats (they run at the plant's 1 kHz).

Motor layout (X configuration, arms at 45 degrees, arm length ``d``, ``a = d / sqrt(2)``), model body FLU::

    motor 0 front-left  (+a, +a)   spins so that its reaction torque is +c f (about +z FLU)
    motor 1 front-right (+a, -a)   -c f
    motor 2 rear-right  (-a, -a)   +c f
    motor 3 rear-left   (-a, +a)   -c f

so ``tau_x = a (f0 - f1 - f2 + f3)``, ``tau_y = a (-f0 - f1 + f2 + f3)``, ``tau_z = c (f0 - f1 + f2 - f3)``,
``T = f0 + f1 + f2 + f3`` (``c`` = yaw moment coefficient, m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from estimators.model.rotations import body_rates, quat_mul
from estimators.model.vehicle import Vehicle

# Sign patterns of the mixer (see module docstring): roll, pitch, yaw contributions of each motor.
_SX = (1.0, -1.0, -1.0, 1.0)
_SY = (-1.0, -1.0, 1.0, 1.0)
_SZ = (1.0, -1.0, 1.0, -1.0)


class Mixer:
    """Collective thrust (N) + body torques (N m, FLU) -> four motor thrusts (N) with limits and first-order lag.

    Desaturation (like PX4's multicopter allocator without airmode): roll/pitch come first, yaw gets what is
    left; at the top the collective is lowered to keep the roll/pitch torque, at the bottom the roll/pitch
    torque is scaled down. Each motor then follows its command with the time constant ``motor_time_constant``.
    """

    def __init__(self, vehicle: Vehicle, dt: float) -> None:
        self.a = vehicle.arm_length / math.sqrt(2.0)
        self.c = vehicle.yaw_moment_coefficient
        self.fmax = vehicle.motor_thrust_max
        tau = vehicle.motor_time_constant
        self.alpha = 1.0 if tau <= 0.0 else 1.0 - math.exp(-dt / tau)
        self.f = [0.0, 0.0, 0.0, 0.0]  # actual motor thrusts, N
        self.cmd = [0.0, 0.0, 0.0, 0.0]  # commanded motor thrusts after limits, N

    def reset(self, thrust_each: float = 0.0) -> None:
        """Set all motors (actual and commanded) to one thrust, N."""
        self.f = [thrust_each] * 4
        self.cmd = [thrust_each] * 4

    def allocate(self, thrust: float, tx: float, ty: float, tz: float) -> list[float]:
        """Motor thrust commands (N) for a wrench, limited to [0, motor_thrust_max] with roll/pitch priority."""
        fmax = self.fmax
        base = 0.25 * (thrust if thrust < 4.0 * fmax else 4.0 * fmax)
        if base < 0.0:
            base = 0.0
        kx = tx / (4.0 * self.a)
        ky = ty / (4.0 * self.a)
        kz = tz / (4.0 * self.c)
        # roll/pitch parts of motors 0..3 (signs _SX, _SY)
        r0, r1, r2, r3 = kx - ky, -kx - ky, -kx + ky, kx + ky
        lo = min(r0, r1, r2, r3)
        hi = max(r0, r1, r2, r3)
        span = hi - lo
        if span > fmax:  # roll/pitch alone cannot fit: scale them down
            s = fmax / span
            r0, r1, r2, r3 = r0 * s, r1 * s, r2 * s, r3 * s
            lo, hi = lo * s, hi * s
        if base + hi > fmax:  # top: lower the collective
            base = fmax - hi
        if base + lo < 0.0:  # bottom: keep the collective, scale roll/pitch
            s = base / -lo
            r0, r1, r2, r3 = r0 * s, r1 * s, r2 * s, r3 * s
        f0, f1, f2, f3 = base + r0, base + r1, base + r2, base + r3
        # yaw (signs _SZ = +, -, +, -): largest k in [0, 1] keeping every motor in range
        k = 1.0
        if kz > 0.0:
            k = min(k, (fmax - f0) / kz, (fmax - f2) / kz, f1 / kz, f3 / kz)
        elif kz < 0.0:
            k = min(k, f0 / -kz, f2 / -kz, (fmax - f1) / -kz, (fmax - f3) / -kz)
        if k < 0.0:
            k = 0.0
        y = k * kz
        out = [f0 + y, f1 - y, f2 + y, f3 - y]
        out = [0.0 if v < 0.0 else (fmax if v > fmax else v) for v in out]
        self.cmd = out
        return out

    def step(self) -> tuple[float, float, float, float]:
        """Advance the motor lag one period; returns the actual (thrust N, tau_x, tau_y, tau_z N m, FLU)."""
        al = self.alpha
        f, c = self.f, self.cmd
        f0 = f[0] + (c[0] - f[0]) * al
        f1 = f[1] + (c[1] - f[1]) * al
        f2 = f[2] + (c[2] - f[2]) * al
        f3 = f[3] + (c[3] - f[3]) * al
        self.f = [f0, f1, f2, f3]
        a = self.a
        return (f0 + f1 + f2 + f3, a * (f0 - f1 - f2 + f3), a * (-f0 - f1 + f2 + f3), self.c * (f0 - f1 + f2 - f3))

    def wrench(self) -> tuple[float, float, float, float]:
        """The actual motors' (thrust N, tau_x, tau_y, tau_z N m, FLU), without advancing the lag."""
        f0, f1, f2, f3 = self.f
        a = self.a
        return (f0 + f1 + f2 + f3, a * (f0 - f1 - f2 + f3), a * (-f0 - f1 + f2 + f3), self.c * (f0 - f1 + f2 - f3))


# ---------------------------------------------------------------------------------------------------------------
# Quaternion helpers (w, x, y, z), plain floats.


def quat_from_thrust_dir_yaw(n1: float, n2: float, n3: float, psi: float) -> tuple[float, float, float, float]:
    """Attitude (model quaternion) whose body z axis is the unit vector ``n`` (NWU) and whose heading is ``psi``.

    Built like PX4's ``bodyzToAttitude``: x_c = (cos psi, sin psi, 0), y_b = z_b x x_c, x_b = y_b x z_b.
    """
    cx, cy = math.cos(psi), math.sin(psi)
    # y_b = z_b x x_c
    y1 = n2 * 0.0 - n3 * cy
    y2 = n3 * cx - n1 * 0.0
    y3 = n1 * cy - n2 * cx
    ny = math.sqrt(y1 * y1 + y2 * y2 + y3 * y3)
    if ny < 1e-6:  # thrust horizontal along the heading: pick any perpendicular
        y1, y2, y3, ny = -cy, cx, 0.0, 1.0
    y1, y2, y3 = y1 / ny, y2 / ny, y3 / ny
    x1 = y2 * n3 - y3 * n2
    x2 = y3 * n1 - y1 * n3
    x3 = y1 * n2 - y2 * n1
    # rotation matrix columns x_b, y_b, z_b -> quaternion
    r00, r01, r02 = x1, y1, n1
    r10, r11, r12 = x2, y2, n2
    r20, r21, r22 = x3, y3, n3
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        return (0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s)
    if r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        return ((r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s)
    if r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        return ((r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s)
    s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
    return ((r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s)


# ---------------------------------------------------------------------------------------------------------------


@dataclass
class RateGains:
    """PX4-style rate PID gains, normalized torque (-1..1 of the axis' maximum torque) per rad/s error."""

    p: tuple[float, float, float]
    i: tuple[float, float, float]
    d: tuple[float, float, float]
    i_limit: float = 0.3


def default_rate_gains(vehicle: Vehicle, bandwidth: tuple[float, float, float] = (18.0, 18.0, 5.0)) -> RateGains:
    """Rate gains tuned for a vehicle: proportional gain = bandwidth * inertia / max torque (per axis).

    PX4's stock numbers (MC_ROLLRATE_P = 0.15) assume a light airframe; the paper's vehicle has I = 0.1 kg m^2,
    so the emulator scales the gains to give the same closed-loop rate bandwidth on any vehicle file.
    """
    tmax = (vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max)
    p = tuple(bw * ii / tm for bw, ii, tm in zip(bandwidth, vehicle.inertia, tmax))
    i = tuple(0.5 * bw * k for bw, k in zip(bandwidth, p))
    return RateGains(p=p, i=i, d=(0.0, 0.0, 0.0))  # type: ignore[arg-type]


class AttitudeController:
    """PX4-like cascade: quaternion attitude error -> P -> body-rate setpoint -> PID -> body torques (N m, FLU).

    Attitude P gains are rad/s per rad (PX4 MC_ROLL_P, MC_PITCH_P, MC_YAW_P); rate gains are normalized torque
    per rad/s (PX4 MC_*RATE_P/I/D), scaled by the vehicle's maximum torque per axis. Rate limits in rad/s.
    """

    def __init__(self, vehicle: Vehicle, dt: float) -> None:
        self.dt = dt
        self.att_p = [6.5, 6.5, 2.8]
        self.rate_max = [math.radians(220.0), math.radians(220.0), math.radians(200.0)]
        g = default_rate_gains(vehicle)
        self.rate_p = list(g.p)
        self.rate_i = list(g.i)
        self.rate_d = list(g.d)
        self.i_limit = g.i_limit
        self.tmax = [vehicle.roll_pitch_torque_max, vehicle.roll_pitch_torque_max, vehicle.yaw_torque_max]
        self.integ = [0.0, 0.0, 0.0]
        self.prev_w = [0.0, 0.0, 0.0]
        self.rate_sp = (0.0, 0.0, 0.0)

    def reset(self) -> None:
        """Clear integrators (done on the ground, like PX4 when landed)."""
        self.integ = [0.0, 0.0, 0.0]

    def attitude_to_rates(
        self, q: tuple[float, ...], qd: tuple[float, ...], yaw_rate_ff: float = 0.0
    ) -> tuple[float, float, float]:
        """Body-rate setpoint (rad/s, FLU) from the current and desired model quaternions (body FLU -> NWU).

        ``yaw_rate_ff``: feed-forward rate about the world z axis (rad/s, NWU: positive counter-clockwise).
        """
        qw, qx, qy, qz = q
        # e = conj(q) * qd
        dw, dx, dy, dz = qd
        ew = qw * dw + qx * dx + qy * dy + qz * dz
        ex = qw * dx - qx * dw - qy * dz + qz * dy
        ey = qw * dy + qx * dz - qy * dw - qz * dx
        ez = qw * dz - qx * dy + qy * dx - qz * dw
        s = 2.0 if ew >= 0.0 else -2.0
        rx = s * ex * self.att_p[0]
        ry = s * ey * self.att_p[1]
        rz = s * ez * self.att_p[2]
        if yaw_rate_ff != 0.0:
            # world z expressed in body: third row of R^T = R's third row
            zx = 2.0 * (qx * qz - qw * qy)
            zy = 2.0 * (qy * qz + qw * qx)
            zz = 1.0 - 2.0 * (qx * qx + qy * qy)
            rx += zx * yaw_rate_ff
            ry += zy * yaw_rate_ff
            rz += zz * yaw_rate_ff
        m = self.rate_max
        return (min(max(rx, -m[0]), m[0]), min(max(ry, -m[1]), m[1]), min(max(rz, -m[2]), m[2]))

    def rates_to_torque(
        self, rate_sp: tuple[float, float, float], w: tuple[float, float, float], integrate: bool
    ) -> tuple[float, float, float]:
        """Body torques (N m, FLU) from the rate setpoint and the measured body rates (rad/s, FLU).

        Runs every ``self.dt`` seconds (the rate-loop period). Output saturated at the axis' maximum torque.
        """
        self.rate_sp = rate_sp
        dt = self.dt
        kp, ki, kd, integ, prev, tm = self.rate_p, self.rate_i, self.rate_d, self.integ, self.prev_w, self.tmax
        w0, w1, w2 = w
        e0, e1, e2 = rate_sp[0] - w0, rate_sp[1] - w1, rate_sp[2] - w2
        if integrate:
            lim = self.i_limit
            i0 = integ[0] + ki[0] * e0 * dt
            i1 = integ[1] + ki[1] * e1 * dt
            i2 = integ[2] + ki[2] * e2 * dt
            integ[0] = lim if i0 > lim else (-lim if i0 < -lim else i0)
            integ[1] = lim if i1 > lim else (-lim if i1 < -lim else i1)
            integ[2] = lim if i2 > lim else (-lim if i2 < -lim else i2)
        inv = 1.0 / dt
        u0 = kp[0] * e0 + integ[0] - kd[0] * (w0 - prev[0]) * inv
        u1 = kp[1] * e1 + integ[1] - kd[1] * (w1 - prev[1]) * inv
        u2 = kp[2] * e2 + integ[2] - kd[2] * (w2 - prev[2]) * inv
        self.prev_w = [w0, w1, w2]
        u0 = 1.0 if u0 > 1.0 else (-1.0 if u0 < -1.0 else u0)
        u1 = 1.0 if u1 > 1.0 else (-1.0 if u1 < -1.0 else u1)
        u2 = 1.0 if u2 > 1.0 else (-1.0 if u2 < -1.0 else u2)
        return (u0 * tm[0], u1 * tm[1], u2 * tm[2])


def px4_vertical_integral(int_z: float, gain: float, error: float, acc: float, g: float, dt: float) -> float:
    """PX4's vertical velocity integrator (``PositionControl``): the climb-rate error ``error`` (m/s, up) times
    MPC_Z_VEL_I_ACC ``gain`` integrated over ``dt`` unless the acceleration setpoint ``acc`` (m/s^2, up) is at its
    limit in the error's direction (the thrust saturated: anti-windup), the integral kept within +-g. It integrates
    far from the setpoint too: a climb held back by a wrong hover thrust is still pushed up."""
    if (acc >= g and error >= 0.0) or (acc <= -0.8 * g and error <= 0.0):
        return int_z
    return min(max(int_z + gain * error * dt, -g), g)


class PositionController:
    """Cascaded P position -> PI velocity -> acceleration -> thrust vector, in the model frame (NWU).

    Uses the autopilot's own hover-thrust belief (PX4 MPC_THR_HOVER / ArduPilot MOT_THST_HOVER) to turn an
    acceleration into normalized thrust, as PX4's position controller does; a wrong belief shows up as a
    transient the velocity integrator removes. Output: (desired model quaternion, normalized thrust 0..1).
    """

    def __init__(self, gravity: float) -> None:
        self.g = gravity
        self.xy_p = 0.95
        self.z_p = 1.0
        self.xy_vel_p = 1.8
        self.xy_vel_i = 0.4
        self.z_vel_p = 4.0
        self.z_vel_i = 2.0
        self.xy_speed_max = 5.0
        self.z_speed_up = 3.0
        self.z_speed_down = 1.5
        self.tilt_max = math.radians(35.0)
        self.int_x = 0.0
        self.int_y = 0.0
        self.int_z = 0.0
        #: the last update's vertical acceleration setpoint (m/s^2, up; the integrator is a part of it) and vertical
        #: thrust (normalized, up): what PX4's hover thrust estimator reads (its local position setpoint)
        self.acc_up = 0.0
        self.thrust_up = 0.0
        #: PX4's vertical integrator (:func:`px4_vertical_integral`) instead of the near-setpoint one
        self.px4_vertical_integrator = False

    def reset(self) -> None:
        """Clear the velocity integrators."""
        self.int_x = self.int_y = self.int_z = 0.0

    def update(
        self,
        pos: tuple[float, float, float],
        vel: tuple[float, float, float],
        pos_sp: tuple[float | None, float | None, float | None],
        vel_ff: tuple[float, float, float],
        yaw_sp: float,
        hover_norm: float,
        dt: float,
        xy_speed_max: float | None = None,
        z_speed_up: float | None = None,
        z_speed_down: float | None = None,
    ) -> tuple[tuple[float, float, float, float], float]:
        """One update; ``pos_sp`` components may be ``None`` (velocity-only on that axis). SI units, NWU."""
        vx, vy, vz = vel_ff
        if pos_sp[0] is not None:
            vx += self.xy_p * (pos_sp[0] - pos[0])
        if pos_sp[1] is not None:
            vy += self.xy_p * (pos_sp[1] - pos[1])
        if pos_sp[2] is not None:
            vz += self.z_p * (pos_sp[2] - pos[2])
        vmax = self.xy_speed_max if xy_speed_max is None else xy_speed_max
        h = math.hypot(vx, vy)
        if h > vmax:
            vx, vy = vx * vmax / h, vy * vmax / h
        up = self.z_speed_up if z_speed_up is None else z_speed_up
        dn = self.z_speed_down if z_speed_down is None else z_speed_down
        vz = min(max(vz, -dn), up)
        ex, ey, ez = vx - vel[0], vy - vel[1], vz - vel[2]
        ax = self.xy_vel_p * ex + self.int_x
        ay = self.xy_vel_p * ey + self.int_y
        az = self.z_vel_p * ez + self.int_z
        g = self.g
        if self.px4_vertical_integrator:
            self.int_z = px4_vertical_integral(self.int_z, self.z_vel_i, ez, az, g, dt)
        # anti-windup: integrate only while the output is not limited
        elif -0.8 * g < az < g and abs(ez) < 0.5:  # and only near the setpoint (no wind-up while braking)
            self.int_z = min(max(self.int_z + self.z_vel_i * ez * dt, -4.0), 4.0)
        az = min(max(az, -0.8 * g), g)
        hmax = math.tan(self.tilt_max) * (g + az)
        ha = math.hypot(ax, ay)
        if ha > hmax:
            ax, ay = ax * hmax / ha, ay * hmax / ha
        elif abs(ex) < 0.5 and abs(ey) < 0.5:
            self.int_x = min(max(self.int_x + self.xy_vel_i * ex * dt, -2.0), 2.0)
            self.int_y = min(max(self.int_y + self.xy_vel_i * ey * dt, -2.0), 2.0)
        tx, ty, tz = ax, ay, g + az
        n = math.sqrt(tx * tx + ty * ty + tz * tz)
        thrust = n / g * hover_norm
        q = quat_from_thrust_dir_yaw(tx / n, ty / n, tz / n, yaw_sp)
        thrust = min(max(thrust, 0.0), 1.0)
        self.acc_up, self.thrust_up = az, thrust * tz / n
        return q, thrust


def px4_thrust_newtons(thrust_norm: float, thrust_max: float) -> float:
    """PX4 multicopter thrust semantics: normalized collective thrust 0..1 of the maximum -> N (linear,
    THR_MDL_FAC = 0). Negative values (reverse thrust) are clamped to 0 on a quadrotor."""
    return min(max(thrust_norm, 0.0), 1.0) * thrust_max


def ardupilot_climb_rate(thrust: float, speed_up: float, speed_down: float) -> float:
    """ArduPilot GUIDED SET_ATTITUDE_TARGET thrust as a climb-rate command (GUID_OPTIONS bit 3 clear), m/s up:
    0.5 -> 0, 1 -> ``speed_up`` (WPNAV_SPEED_UP), 0 -> ``-speed_down`` (WPNAV_SPEED_DN), linear in between."""
    t = min(max(thrust, 0.0), 1.0)
    return (t - 0.5) * 2.0 * (speed_up if t >= 0.5 else speed_down)


def ardupilot_throttle_newtons(thrust: float, phi: float, theta: float, boost: bool, thrust_max: float) -> float:
    """ArduPilot GUIDED thrust-as-throttle (GUID_OPTIONS bit 3): throttle 0..1, times 1/cos(tilt) when
    ATC_ANGLE_BOOST is on, capped at full throttle -> N."""
    thr = min(max(thrust, 0.0), 1.0)
    if boost:
        thr = min(angle_boost(thr, phi, theta), 1.0)
    return thr * thrust_max


def angle_boost(throttle: float, phi: float, theta: float) -> float:
    """ArduPilot's angle boost: throttle / cos(tilt), with cos(tilt) floored at 0.5 (AC_AttitudeControl_Multi)."""
    ct = math.cos(phi) * math.cos(theta)
    return throttle / max(ct, 0.5)


__all__ = [
    "AttitudeController",
    "Mixer",
    "PositionController",
    "RateGains",
    "angle_boost",
    "ardupilot_climb_rate",
    "ardupilot_throttle_newtons",
    "body_rates",
    "default_rate_gains",
    "px4_thrust_newtons",
    "quat_from_thrust_dir_yaw",
    "quat_mul",
]
