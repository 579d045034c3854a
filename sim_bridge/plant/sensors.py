"""Sensor models: what an autopilot's telemetry (and an optional cable-angle sensor) reports, from the plant.

Called by the in-process simulation after every plant step; returns the measurements *delivered* since the
previous call, each stamped with the time at which it was *sampled* (records of ``estimators.model.measurements``,
model frame: world NWU, body FLU, SI, rad). Each sensor has its own rate, latency (+ uniform jitter) and
seeded white noise; the accelerometer has a constant per-axis bias drawn once from the generator.

Presets (sources and reasons: ``docs/estimation.md``):

``ideal``
    every sensor at 250 Hz, exact values, no latency, no bias.
``px4-typical``
    the rates PX4 streams on its ``onboard`` MAVLink link without any SET_MESSAGE_INTERVAL
    (``src/modules/mavlink/mavlink_main.cpp``: ATTITUDE 100 Hz, HIGHRES_IMU 50 Hz, LOCAL_POSITION_NED 30 Hz),
    a 100 Hz cable-angle sensor read by the companion computer, a few milliseconds of link latency, and the
    noise of a typical 0.5-1 kg quadrotor (EKF2 output for position and attitude, vibration-dominated
    accelerometer after PX4's 30 Hz low-pass, a calibrated accelerometer's residual bias).
``px4-fast``
    the same noise with the rates a user would request for this controller with SET_MESSAGE_INTERVAL
    (ATTITUDE 250 Hz, HIGHRES_IMU 250 Hz, ODOMETRY 100 Hz, cable angle 250 Hz).

A sensor samples at the first plant step at or after its scheduled time (its phase is random in the noisy
presets), so the sample time is a plant time and the value is exact at it.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from estimators.errors import UserError
from estimators.model.cable import planar_swing
from estimators.model.frames import wrap_angle
from estimators.model.measurements import Attitude, Imu, LoadAngle, Measurement, PositionVelocity
from estimators.model.rotations import body_rates
from estimators.model.vehicle import Vehicle
from sim_bridge.plant.dynamics import derivative, plant_params


class SensorSpec(NamedTuple):
    """One sensor stream: rate (Hz), latency (s) plus uniform jitter in [0, jitter) (s), and the white-noise
    standard deviations of its fields (units of the fields, see :class:`Preset`)."""

    rate_hz: float
    latency_s: float
    jitter_s: float
    noise: tuple[float, ...]


class Preset(NamedTuple):
    """A sensor suite.

    position noise: (horizontal position m, vertical position m, horizontal velocity m/s, vertical velocity m/s);
    attitude noise: (roll and pitch rad, yaw rad, body rates rad/s); imu noise: (specific force m/s^2,
    gyro rad/s); load noise: (angle rad). accel_bias: standard deviation of the constant per-axis
    accelerometer bias (m/s^2). random_phase: sensors start at a random phase of their period.
    """

    position: SensorSpec
    attitude: SensorSpec
    imu: SensorSpec
    load: SensorSpec
    accel_bias: float
    random_phase: bool


_DEG = math.pi / 180.0

#: Noise of a typical small quadrotor (docs/estimation.md gives the sources).
PX4_NOISE = {
    "position": (0.02, 0.03, 0.03, 0.03),
    "attitude": (0.3 * _DEG, 0.6 * _DEG, 0.01),
    "imu": (0.2, 0.01),
    "load": (0.5 * _DEG,),
    "accel_bias": 0.05,
}


def _px4_preset(position_hz: float, attitude_hz: float, imu_hz: float, load_hz: float) -> Preset:
    """A PX4-like suite at these stream rates (Hz): the latencies, jitters and noise (:data:`PX4_NOISE`) of a
    typical small quadrotor, which the PX4 presets share; sensors at a random phase."""
    return Preset(
        SensorSpec(position_hz, 0.006, 0.003, PX4_NOISE["position"]),
        SensorSpec(attitude_hz, 0.004, 0.003, PX4_NOISE["attitude"]),
        SensorSpec(imu_hz, 0.004, 0.003, PX4_NOISE["imu"]),
        SensorSpec(load_hz, 0.002, 0.002, PX4_NOISE["load"]),
        PX4_NOISE["accel_bias"],
        True,
    )


_PRESETS: dict[str, Preset] = {
    "ideal": Preset(
        SensorSpec(250.0, 0.0, 0.0, (0.0, 0.0, 0.0, 0.0)),
        SensorSpec(250.0, 0.0, 0.0, (0.0, 0.0, 0.0)),
        SensorSpec(250.0, 0.0, 0.0, (0.0, 0.0)),
        SensorSpec(250.0, 0.0, 0.0, (0.0,)),
        0.0,
        False,
    ),
    "px4-typical": _px4_preset(30.0, 100.0, 50.0, 100.0),
    "px4-fast": _px4_preset(100.0, 250.0, 250.0, 250.0),
}

PRESETS: tuple[str, ...] = tuple(_PRESETS)


def preset_spec(name: str) -> Preset:
    """The named preset; an unknown name is a :class:`UserError`."""
    try:
        return _PRESETS[name]
    except KeyError:
        raise UserError(f"unknown sensor preset {name!r} (known: {', '.join(PRESETS)})") from None


class _Stream:
    """Scheduling state of one sensor."""

    __slots__ = ("kind", "next_t", "period", "spec")

    def __init__(self, kind: str, spec: SensorSpec) -> None:
        self.kind = kind
        self.spec = spec
        self.period = 1.0 / spec.rate_hz
        self.next_t: float | None = None


def specific_force_body(x: Sequence[float], accel: Sequence[float], g: float) -> tuple[float, float, float]:
    """Accelerometer specific force in body FLU, ``R^T (xi'' + g e3)`` (m/s^2), from the world acceleration."""
    fx, fy, fz = accel[0], accel[1], accel[2] + g
    sf, cf = math.sin(x[6]), math.cos(x[6])
    st, ct = math.sin(x[7]), math.cos(x[7])
    sp, cp = math.sin(x[8]), math.cos(x[8])
    # columns of R = Rz Ry Rx are the body axes in the world frame; R^T f = their dot products with f
    bx = cp * ct * fx + sp * ct * fy - st * fz
    by = (cp * st * sf - sp * cf) * fx + (sp * st * sf + cp * cf) * fy + ct * sf * fz
    bz = (cp * st * cf + sp * sf) * fx + (sp * st * cf - cp * sf) * fy + ct * cf * fz
    return bx, by, bz


class SensorSuite:
    """The sensors of one simulated vehicle (see the module docstring).

    preset: a name in :data:`PRESETS` (or a :class:`Preset`, e.g. one with scaled noise); vehicle: the TRUE
    vehicle (its gravity and masses give the specific force); rng: the only source of randomness (noise, jitter,
    phases, bias); load_sensor: whether the cable-angle sensor is fitted.
    """

    def __init__(
        self, preset: str | Preset, vehicle: Vehicle, rng: np.random.Generator, *, load_sensor: bool = True
    ) -> None:
        self.name = preset if isinstance(preset, str) else "custom"
        self.preset = preset_spec(preset) if isinstance(preset, str) else preset
        self._rng = rng
        self._p = plant_params(vehicle, "paper")  # the translational acceleration does not depend on it
        self._g = vehicle.gravity
        pr = self.preset
        self._streams = [_Stream("position", pr.position), _Stream("attitude", pr.attitude), _Stream("imu", pr.imu)]
        if load_sensor:
            self._streams.append(_Stream("load", pr.load))
        b = rng.normal(0.0, pr.accel_bias, 3) if pr.accel_bias > 0.0 else np.zeros(3)
        #: the accelerometer's constant bias, m/s^2 body FLU
        self.accel_bias: tuple[float, float, float] = (float(b[0]), float(b[1]), float(b[2]))
        self._pending: list[tuple[float, int, Measurement]] = []
        self._seq = 0
        #: samples taken per sensor kind
        self.sampled: dict[str, int] = {s.kind: 0 for s in self._streams}

    def sample(self, t: float, x: Sequence[float], u: Sequence[float]) -> list[Measurement]:
        """Sample the sensors due at plant time ``t`` (s) from state ``x`` and input ``u`` (the 18/13-float
        vectors of ``sim_bridge.plant.dynamics``); return the records delivered in (previous call, t]."""
        for s in self._streams:
            if s.next_t is None:
                s.next_t = t + (self._rng.uniform(0.0, s.period) if self.preset.random_phase else 0.0)
            if t + 1e-9 < s.next_t:
                continue
            rec = self._measure(s, t, x, u)
            self.sampled[s.kind] += 1
            spec = s.spec
            delay = spec.latency_s + (spec.jitter_s * self._rng.random() if spec.jitter_s > 0.0 else 0.0)
            heapq.heappush(self._pending, (t + delay, self._seq, rec))
            self._seq += 1
            while s.next_t <= t + 1e-9:
                s.next_t += s.period
        out: list[Measurement] = []
        pending = self._pending
        while pending and pending[0][0] <= t + 1e-9:
            out.append(heapq.heappop(pending)[2])
        return out

    def _noise(self, sigmas: Sequence[float], n: int) -> list[float]:
        """n noise samples; sigmas[i] scales the i-th (zeros cost no random draw)."""
        if not any(sigmas):
            return [0.0] * n
        z = self._rng.standard_normal(n).tolist()
        return [a * b for a, b in zip(z, sigmas)]

    def _measure(self, s: _Stream, t: float, x: Sequence[float], u: Sequence[float]) -> Measurement:
        kind, sig = s.kind, s.spec.noise
        if kind == "position":
            sxy, sz, svxy, svz = sig
            e = self._noise((sxy, sxy, sz, svxy, svxy, svz), 6)
            return PositionVelocity(t, x[0] + e[0], x[1] + e[1], x[2] + e[2], x[3] + e[3], x[4] + e[4], x[5] + e[5])
        if kind == "attitude":
            sa, sy, sr = sig
            e = self._noise((sa, sa, sy, sr, sr, sr), 6)
            p, q, r = body_rates(x[6], x[7], x[9], x[10], x[11])
            return Attitude(t, x[6] + e[0], x[7] + e[1], wrap_angle(x[8] + e[2]), p + e[3], q + e[4], r + e[5])
        if kind == "imu":
            sa, sg = sig
            e = self._noise((sa, sa, sa, sg, sg, sg), 6)
            acc = derivative(t, x, u, self._p)
            fx, fy, fz = specific_force_body(x, acc[3:6], self._g)
            p, q, r = body_rates(x[6], x[7], x[9], x[10], x[11])
            b = self.accel_bias
            return Imu(t, fx + b[0] + e[0], fy + b[1] + e[1], fz + b[2] + e[2], p + e[3], q + e[4], r + e[5])
        ay, ax, _, _ = planar_swing(x[12], x[13], x[14], x[15], x[16], x[17])
        e = self._noise((sig[0], sig[0]), 2)
        return LoadAngle(t, ax + e[0], ay + e[1])


__all__ = [
    "PRESETS",
    "PX4_NOISE",
    "Preset",
    "SensorSpec",
    "SensorSuite",
    "preset_spec",
    "specific_force_body",
]
