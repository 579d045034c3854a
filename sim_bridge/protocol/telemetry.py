"""Telemetry generation: the one place where the plant state becomes MAVLink telemetry messages.

What the emulated autopilot reports is one of

- the plant truth (sensor preset ``ideal``, the default), optionally with the legacy ad-hoc white noise
  (``noise`` > 0 scales typical EKF / IMU noise levels);
- the issue-3 sensor models (``sim_bridge.plant.sensors``, presets ``px4-typical`` and ``px4-fast``): each sensor
  group (position + velocity; attitude + body rates; accelerometer + gyro; cable angle) is sampled from the plant
  state ``latency + U(0, jitter)`` seconds before the message is sent (a plant-step history is kept for that),
  stamped with that sample time, and carries the preset's white noise; the accelerometer also carries the
  preset's constant per-axis bias. The message RATES are the MAVLink stream intervals (flavour defaults or
  SET_MESSAGE_INTERVAL), not the preset's rates. All randomness comes from one seeded generator (re-seeded with
  a deterministic child of its seed when lockstep streaming starts: :meth:`TelemetrySource.rephase`).

Every model-frame quantity is converted to MAVLink's NED / FRD with ``estimators.model.frames`` only.

Wire conventions (see ``docs/emulator.md``):

- local frame: NED with origin at home (where the vehicle boots), ``z = -altitude``;
- global position: flat-earth around the home point ``HOME`` (lat, lon in degrees, altitude AMSL in m);
- ODOMETRY: frame_id LOCAL_NED, child_frame_id BODY_FRD, velocity in body FRD (as PX4 sends it);
- load-angle sensor: ``DEBUG_VECT`` named ``"LOADANG"``: x = swing angle in the North-Down plane
  ``atan2(r_N, r_D)`` (positive with the load north of the vehicle), y = swing angle in the East-Down plane
  ``atan2(r_E, r_D)`` (positive with the load east), z = total swing angle from the vertical, all rad, where
  ``r`` is the unit cable vector from the vehicle to the load in NED; time_usec = simulation time;
- the load as its own system: GLOBAL_POSITION_INT of the load (sysid 2, compid 35) like ArduPilot's SITL.

This module samples the plant into a :class:`Snapshot` (:class:`TelemetrySource`); the MAVLink messages are built
from a snapshot in ``sim_bridge.protocol.messages``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.model.frames import (
    euler_to_quaternion,
    model_body_to_frd,
    model_euler_to_ned,
    model_quaternion_to_ned,
    model_to_ned_vector,
    wrap_angle,
)
from sim_bridge.inner.airframe import body_rates
from sim_bridge.plant.dynamics import PlantParams, derivative
from sim_bridge.plant.sensors import preset_spec, specific_force_body

EARTH_RADIUS = 6378137.0  # m (WGS-84 equatorial), flat-earth offsets only


@dataclass(frozen=True)
class Home:
    """Home point: latitude and longitude in degrees, altitude AMSL in m (PX4 SITL's default location)."""

    lat: float = 47.397742
    lon: float = 8.545594
    alt: float = 488.0


@dataclass
class Snapshot:
    """Everything the telemetry messages report at one instant, in MAVLink conventions (NED / FRD, SI)."""

    t_us: int
    roll: float
    pitch: float
    yaw: float
    q: tuple[float, float, float, float]
    p: float
    qr: float
    r: float
    pos: tuple[float, float, float]
    vel: tuple[float, float, float]
    acc: tuple[float, float, float]  # specific force, body FRD, m/s^2
    lat: int
    lon: int
    alt_mm: int
    rel_alt_mm: int
    load_pos: tuple[float, float, float]
    load_vel: tuple[float, float, float]
    load_lat: int
    load_lon: int
    load_alt_mm: int
    load_rel_alt_mm: int
    swing_n: float
    swing_e: float
    swing: float
    gyro: tuple[float, float, float]  # IMU gyro, rad/s FRD (the attitude group's rates are p, qr, r)
    t_pos_us: int  # sample times (µs) of the position, attitude, IMU and cable-angle groups
    t_att_us: int
    t_imu_us: int
    t_load_us: int


def _rot_t_times(phi: float, theta: float, psi: float, v: Sequence[float]) -> tuple[float, float, float]:
    """R^T v for R = Rz(psi) Ry(theta) Rx(phi) (world -> body), model frame."""
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    r00, r01, r02 = cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf
    r10, r11, r12 = sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf
    r20, r21, r22 = -st, ct * sf, ct * cf
    x, y, z = v
    return (r00 * x + r10 * y + r20 * z, r01 * x + r11 * y + r21 * z, r02 * x + r12 * y + r22 * z)


class TelemetrySource:
    """Builds :class:`Snapshot` objects from the plant state (see the module docstring).

    params: the plant's parameters; home: the local origin; noise, rng: the legacy ad-hoc noise scale and its
    generator (only with ``sensors="ideal"``); sensors: a preset of ``sim_bridge.plant.sensors.PRESETS``;
    sensor_rng: the only source of randomness of the sensor models (bias, noise, latency jitter); step_us: the
    plant step (µs), the grid of the sample times.
    """

    def __init__(
        self,
        params: PlantParams,
        home: Home,
        noise: float = 0.0,
        rng: np.random.Generator | None = None,
        *,
        sensors: str = "ideal",
        sensor_rng: np.random.Generator | None = None,
        step_us: int = 1000,
    ) -> None:
        self.p = params
        self.home = home
        self.noise = noise
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._cos_lat = math.cos(math.radians(home.lat))
        self.sensors = sensors
        pr = preset_spec(sensors)
        self.preset = pr
        groups = (pr.position, pr.attitude, pr.imu, pr.load)
        #: True when the preset adds noise, bias or latency (otherwise the snapshot is the truth)
        self.modelled = pr.accel_bias > 0.0 or any(
            g.latency_s > 0.0 or g.jitter_s > 0.0 or any(g.noise) for g in groups
        )
        if self.modelled and noise > 0.0:
            raise ValueError("the legacy noise scale and a sensor preset other than 'ideal' exclude each other")
        self.srng = sensor_rng if sensor_rng is not None else np.random.default_rng(0)
        b = self.srng.normal(0.0, pr.accel_bias, 3) if pr.accel_bias > 0.0 else np.zeros(3)
        #: the accelerometer's constant bias, m/s^2 body FLU (drawn as ``sim_bridge.plant.sensors.SensorSuite`` does)
        self.accel_bias: tuple[float, float, float] = (float(b[0]), float(b[1]), float(b[2]))
        self._delay = tuple((g.latency_s, g.jitter_s) for g in groups)
        max_delay = max(lat + jit for lat, jit in self._delay)
        #: True when :meth:`record` must be called after every plant step (a preset with latency)
        self.needs_history = self.modelled and max_delay > 0.0
        self.step_us = step_us
        self._hist: deque[tuple[int, tuple[float, ...], tuple[float, ...], bool]] = deque(
            maxlen=int(max_delay * 1e6 / step_us) + 3
        )
        self._last_target = [0, 0, 0, 0]
        #: the estimator's error (``sim_bridge.plant.ekf_error.EkfError``) added to position and velocity, or None
        self.ekf: Any = None
        self._seed_seq = getattr(self.srng.bit_generator, "seed_seq", None)

    def rephase(self) -> None:
        """Lockstep streaming (re)starts: continue with a fresh generator, the next child of the sensor generator's
        seed sequence, so that the noise from here on does not depend on how many snapshots the free-running
        clock took before (a wall-clock matter). The bias is kept."""
        if self.modelled and self._seed_seq is not None:
            self.srng = np.random.default_rng(self._seed_seq.spawn(1)[0])

    def record(self, t_us: int, x: Sequence[float], u: Sequence[float], on_ground: bool = False) -> None:
        """Remember the plant state and input at ``t_us`` (called after every plant step when latency is modelled)."""
        self._hist.append((t_us, tuple(x), tuple(u), on_ground))

    def _latlon(self, n: float, e: float, d: float) -> tuple[int, int, int, int]:
        lat = self.home.lat + math.degrees(n / EARTH_RADIUS)
        lon = self.home.lon + math.degrees(e / (EARTH_RADIUS * self._cos_lat))
        return (round(lat * 1e7), round(lon * 1e7), round((self.home.alt - d) * 1000.0), round(-d * 1000.0))

    def snapshot(self, t_us: int, x: Sequence[float], u: Sequence[float], on_ground: bool = False) -> Snapshot:
        """Telemetry values at simulation time ``t_us`` (µs) for state ``x`` and input ``u`` (model frame);
        ``on_ground``: the vehicle rests on the ground (held at rest: the accelerometer reads 1 g up)."""
        if self.modelled:
            return self._sensed(t_us, x, u, on_ground)
        phi, theta, psi = x[6], x[7], x[8]
        wx, wy, wz = body_rates(phi, theta, x[9], x[10], x[11])
        f_body = _rot_t_times(phi, theta, psi, self._world_specific_force(x, u, on_ground))
        if self.ekf is not None:
            ep, ev = self.ekf.position_error(), self.ekf.velocity_error()
            et = self.ekf.tilt_error()  # the attitude reported is the estimate, as EKF2's
            phi, theta = phi + et[0], theta + et[1]
            pos = model_to_ned_vector(x[0] + ep[0], x[1] + ep[1], x[2] + ep[2])
            vel = model_to_ned_vector(x[3] + ev[0], x[4] + ev[1], x[5] + ev[2])
        else:
            pos = model_to_ned_vector(x[0], x[1], x[2])
            vel = model_to_ned_vector(x[3], x[4], x[5])
        rn, re, rd = model_to_ned_vector(x[12], x[13], x[14])
        if self.noise > 0.0:
            k = self.noise
            nz = self.rng.standard_normal(17)
            phi += k * 0.005 * nz[0]
            theta += k * 0.005 * nz[1]
            psi += k * 0.01 * nz[2]
            wx, wy, wz = wx + k * 0.01 * nz[3], wy + k * 0.01 * nz[4], wz + k * 0.01 * nz[5]
            f_body = (f_body[0] + k * 0.2 * nz[6], f_body[1] + k * 0.2 * nz[7], f_body[2] + k * 0.2 * nz[8])
            pos = (pos[0] + k * 0.02 * nz[9], pos[1] + k * 0.02 * nz[10], pos[2] + k * 0.03 * nz[11])
            vel = (vel[0] + k * 0.03 * nz[12], vel[1] + k * 0.03 * nz[13], vel[2] + k * 0.03 * nz[14])
            swing_noise = (k * 0.009 * nz[15], k * 0.009 * nz[16])
        else:
            swing_noise = (0.0, 0.0)
        rates = model_body_to_frd(wx, wy, wz)
        return self._build(
            t_us,
            x,
            (phi, theta, psi),
            rates,
            pos,
            vel,
            model_body_to_frd(*f_body),
            rates,
            math.atan2(rn, rd) + swing_noise[0],
            math.atan2(re, rd) + swing_noise[1],
            math.atan2(math.hypot(rn, re), rd),
            (t_us, t_us, t_us, t_us),
        )

    def _world_specific_force(
        self, x: Sequence[float], u: Sequence[float], on_ground: bool
    ) -> tuple[float, float, float]:
        """Specific force ``xi'' + g e3`` in the world frame (m/s^2); the ground holds the vehicle at rest."""
        g = self.p.g
        if on_ground:
            return (0.0, 0.0, g)
        dx = derivative(0.0, x, u, self.p)
        return (dx[3], dx[4], dx[5] + g)

    def _sample(
        self, group: int, t_us: int, jitter_u: float, x: Sequence[float], u: Sequence[float], on_ground: bool
    ) -> tuple[int, Sequence[float], Sequence[float], bool]:
        """(sample time µs, state, input) of a sensor group: the newest recorded plant step at or before
        ``t_us - latency - jitter`` (never earlier than the group's previous sample)."""
        lat, jit = self._delay[group]
        target = t_us - round((lat + jit * jitter_u) * 1e6)
        target = max(target, self._last_target[group])
        self._last_target[group] = target
        if target >= t_us or not self._hist:
            return t_us, x, u, on_ground
        hist = self._hist
        for entry in reversed(hist):
            if entry[0] <= target:
                return entry
        return hist[0]

    def _sensed(self, t_us: int, x: Sequence[float], u: Sequence[float], on_ground: bool) -> Snapshot:
        """The snapshot with the preset's latency, noise and bias (module docstring)."""
        pr = self.preset
        z = self.srng.standard_normal(20).tolist()
        jit = self.srng.random(4).tolist()
        # position + velocity
        tp, xp, _, _ = self._sample(0, t_us, jit[0], x, u, on_ground)
        sxy, sz, svxy, svz = pr.position.noise
        ep, ev = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        if self.ekf is not None:
            ep, ev = self.ekf.position_error(), self.ekf.velocity_error()
        pos = model_to_ned_vector(xp[0] + ep[0] + sxy * z[0], xp[1] + ep[1] + sxy * z[1], xp[2] + ep[2] + sz * z[2])
        vel = model_to_ned_vector(xp[3] + ev[0] + svxy * z[3], xp[4] + ev[1] + svxy * z[4], xp[5] + ev[2] + svz * z[5])
        # attitude + body rates
        ta, xa, _, _ = self._sample(1, t_us, jit[1], x, u, on_ground)
        sa, sy, sr = pr.attitude.noise
        et = (0.0, 0.0) if self.ekf is None else self.ekf.tilt_error()  # the estimate's tilt error, as EKF2's
        euler = (xa[6] + et[0] + sa * z[6], xa[7] + et[1] + sa * z[7], wrap_angle(xa[8] + sy * z[8]))
        w = body_rates(xa[6], xa[7], xa[9], xa[10], xa[11])
        rates = model_body_to_frd(w[0] + sr * z[9], w[1] + sr * z[10], w[2] + sr * z[11])
        # accelerometer (bias + noise) + gyro
        ti, xi, ui, gi = self._sample(2, t_us, jit[2], x, u, on_ground)
        sacc, sg = pr.imu.noise
        fw = self._world_specific_force(xi, ui, gi)
        f = specific_force_body(xi, (fw[0], fw[1], fw[2] - self.p.g), self.p.g)
        b = self.accel_bias
        acc = model_body_to_frd(f[0] + b[0] + sacc * z[12], f[1] + b[1] + sacc * z[13], f[2] + b[2] + sacc * z[14])
        wi = body_rates(xi[6], xi[7], xi[9], xi[10], xi[11])
        gyro = model_body_to_frd(wi[0] + sg * z[15], wi[1] + sg * z[16], wi[2] + sg * z[17])
        # cable angle
        tl, xl, _, _ = self._sample(3, t_us, jit[3], x, u, on_ground)
        sl = pr.load.noise[0]
        rn, re, rd = model_to_ned_vector(xl[12], xl[13], xl[14])
        sn = math.atan2(rn, rd) + sl * z[18]
        se = math.atan2(re, rd) + sl * z[19]
        total = (
            math.atan(math.hypot(math.tan(sn), math.tan(se)))
            if max(abs(sn), abs(se)) < 1.5
            else math.atan2(math.hypot(rn, re), rd)
        )
        return self._build(t_us, x, euler, rates, pos, vel, acc, gyro, sn, se, total, (tp, ta, ti, tl))

    def _build(
        self,
        t_us: int,
        x: Sequence[float],
        euler: tuple[float, float, float],
        rates: tuple[float, float, float],
        pos: tuple[float, float, float],
        vel: tuple[float, float, float],
        acc: tuple[float, float, float],
        gyro: tuple[float, float, float],
        swing_n: float,
        swing_e: float,
        swing: float,
        stamps: tuple[int, int, int, int],
    ) -> Snapshot:
        """Assemble a snapshot; euler: model ZYX angles (rad); rates, acc, gyro: FRD; pos, vel: NED; the load's
        own position (its second MAVLink system) is the truth of ``x``."""
        phi, theta, psi = euler
        roll, pitch, yaw = model_euler_to_ned(phi, theta, psi)
        q = model_quaternion_to_ned(*euler_to_quaternion(phi, theta, psi))
        l = self.p.l
        load_pos = model_to_ned_vector(x[0] + l * x[12], x[1] + l * x[13], x[2] + l * x[14])
        load_vel = model_to_ned_vector(x[3] + l * x[15], x[4] + l * x[16], x[5] + l * x[17])
        lat, lon, alt, rel = self._latlon(*pos)
        llat, llon, lalt, lrel = self._latlon(*load_pos)
        return Snapshot(
            t_us,
            roll,
            pitch,
            yaw,
            q,
            rates[0],
            rates[1],
            rates[2],
            pos,
            vel,
            acc,
            lat,
            lon,
            alt,
            rel,
            load_pos,
            load_vel,
            llat,
            llon,
            lalt,
            lrel,
            swing_n,
            swing_e,
            swing,
            gyro,
            *stamps,
        )
