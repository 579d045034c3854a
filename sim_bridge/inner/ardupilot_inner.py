"""ArduPilot Copter's inner-loop pieces the emulator's ArduPilot flavour adds to its attitude cascade, modelled on
their structure (ArduPilot master: AC_AttitudeControl, AP_Motors, Copter's throttle-hover learning; read, not
copied):

- :class:`AttitudeShaper`: ArduPilot does not hand a new attitude straight to its attitude controller. It keeps an
  *attitude target* that moves towards the requested attitude with the square-root controller: per body axis a
  rate ``sqrt_controller(error, 1 / ATC_INPUT_TC, ATC_ACCEL_*_MAX)`` whose change per step is limited by the same
  acceleration (``input_shaping_angle``), integrated into the target; the attitude controller then tracks the
  target with ATC_ANG_*_P plus the target's rate as feed-forward. The requested tilt is limited to ANGLE_MAX.
- :func:`thrust_curve` / :func:`throttle_to_actuator`: MOT_THST_EXPO, the motors' thrust fraction
  ``(1 - e) u + e u^2`` of the actuator command ``u``, which ArduPilot inverts so that its throttle is linear in
  thrust (the emulated rotors follow the curve with the physical expo; a mismatched parameter shows up as a
  thrust error).
- :class:`HoverLearner`: MOT_THST_HOVER learned in flight (MOT_HOVER_LEARN 2) with the 10 s time constant, only
  in a level, near-zero-climb hover in a mode that controls the throttle.

Frames: the model frame (body FLU, world NWU) as the rest of ``sim_bridge``; rad, rad/s, rad/s^2, s.
"""

from __future__ import annotations

import math

from estimators.model.rotations import Quat, quat_mul, quat_normalize
from sim_bridge.inner.airframe import quat_from_thrust_dir_yaw

#: ArduPilot's defaults: ATC_INPUT_TC 0.15 s; ATC_ACCEL_R_MAX / P_MAX 110000, Y_MAX 27000 cdeg/s^2
INPUT_TC_S = 0.15
ACCEL_MAX_RAD_S2 = (math.radians(1100.0), math.radians(1100.0), math.radians(270.0))
HOVER_LEARN_TC_S = 10.0


def sqrt_controller(error: float, p: float, second_ord_lim: float, dt: float) -> float:
    """The square-root controller: linear (``p error``) near zero, ``sqrt(2 a (|e| - a / (2 p^2)))`` beyond, so
    that the response decelerates at the limit ``a``; never more than the error can absorb in ``dt``."""
    if second_ord_lim <= 0.0 or p <= 0.0:
        out = error * p
    else:
        linear_dist = second_ord_lim / (p * p)
        if abs(error) > linear_dist:
            out = math.copysign(math.sqrt(2.0 * second_ord_lim * (abs(error) - 0.5 * linear_dist)), error)
        else:
            out = error * p
    if dt > 0.0:
        lim = abs(error) / dt
        out = min(max(out, -lim), lim)
    return out


def input_shaping_angle(
    error: float, input_tc: float, accel_max: float, target_rate: float, dt: float, ff_rate: float = 0.0
) -> float:
    """The target's new rate: the square-root controller's rate for the remaining error plus the request's own
    rate (feed-forward), reached from the current target rate at no more than ``accel_max``."""
    desired = sqrt_controller(error, 1.0 / max(input_tc, 0.01), accel_max, dt) + ff_rate
    if accel_max > 0.0:
        d = accel_max * dt
        desired = min(max(desired, target_rate - d), target_rate + d)
    return desired


def limit_tilt(q: Quat, tilt_max: float) -> Quat:
    """The attitude ``q`` with its tilt (angle of the body z axis from the vertical) limited to ``tilt_max`` rad,
    the tilt's direction and the heading kept (ANGLE_MAX)."""
    w, x, y, z = q
    n1, n2, n3 = 2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)  # body z in the world
    if n3 >= math.cos(tilt_max):
        return q
    h = math.hypot(n1, n2)
    if h < 1e-12:  # upside down: any direction
        n1, n2, h = 1.0, 0.0, 1.0
    st, ct = math.sin(tilt_max), math.cos(tilt_max)
    psi = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return quat_from_thrust_dir_yaw(n1 / h * st, n2 / h * st, ct, psi)  # type: ignore[return-value]


class AttitudeShaper:
    """ArduPilot's attitude target: moves towards the requested attitude by input shaping (module docstring)."""

    def __init__(self) -> None:
        self.input_tc = INPUT_TC_S
        self.accel_max = list(ACCEL_MAX_RAD_S2)
        self.target: Quat | None = None
        self.rate = [0.0, 0.0, 0.0]  # the target's body rates, rad/s (FLU)

    def reset(self, q: Quat) -> None:
        """Start the target at attitude ``q``, at rest (done on the ground and on arming)."""
        self.target = q
        self.rate = [0.0, 0.0, 0.0]

    def update(
        self, q_now: Quat, q_desired: Quat, dt: float, yaw_rate_ff: float = 0.0
    ) -> tuple[Quat, tuple[float, float, float]]:
        """Advance the target ``dt`` s towards ``q_desired``, which itself turns at ``yaw_rate_ff`` (rad/s about the
        world vertical; it enters the shaping, as ArduPilot's input_quaternion takes the request's rate);
        (target attitude, its body rate feed-forward)."""
        if self.target is None:
            self.reset(q_now)
        t = self.target
        assert t is not None
        e = quat_mul((t[0], -t[1], -t[2], -t[3]), q_desired)  # desired relative to the target, body axes
        s = 2.0 if e[0] >= 0.0 else -2.0
        err = (s * e[1], s * e[2], s * e[3])
        tc, am, r = self.input_tc, self.accel_max, self.rate
        w, x, y, z = t
        # the world vertical seen from the target's body axes (third row of its rotation matrix)
        wz = (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
        for i in range(3):
            r[i] = input_shaping_angle(err[i], tc, am[i], r[i], dt, wz[i] * yaw_rate_ff)
        h = 0.5 * dt
        self.target = quat_normalize(quat_mul(t, (1.0, r[0] * h, r[1] * h, r[2] * h)))
        return self.target, (r[0], r[1], r[2])


def thrust_curve(actuator: float, expo: float) -> float:
    """Thrust fraction 0..1 of an actuator command 0..1 (MOT_THST_EXPO: ``(1 - e) u + e u^2``)."""
    u = min(max(actuator, 0.0), 1.0)
    return (1.0 - expo) * u + expo * u * u


def throttle_to_actuator(throttle: float, expo: float) -> float:
    """ArduPilot's linearization: the actuator command whose thrust fraction is ``throttle`` under MOT_THST_EXPO."""
    t = min(max(throttle, 0.0), 1.0)
    if abs(expo) < 1e-6:
        return t
    return ((expo - 1.0) + math.sqrt((1.0 - expo) ** 2 + 4.0 * expo * t)) / (2.0 * expo)


class HoverLearner:
    """MOT_THST_HOVER learned in flight (the throttle that holds a level hover), 10 s time constant."""

    def __init__(self, value: float) -> None:
        self.value = value

    def update(self, throttle: float, climb_rate: float, tilt: float, dt: float) -> bool:
        """Learn from one period of a level, near-zero-climb hover (|climb| < 0.6 m/s, tilt < 5 deg, throttle > 0);
        True when the value changed."""
        if throttle <= 0.0 or abs(climb_rate) >= 0.6 or abs(tilt) >= math.radians(5.0):
            return False
        v = self.value + dt / (dt + HOVER_LEARN_TC_S) * (throttle - self.value)
        self.value = min(max(v, 0.125), 0.6875)  # ArduPilot's MOT_THST_HOVER range
        return True


__all__ = [
    "AttitudeShaper",
    "HoverLearner",
    "input_shaping_angle",
    "limit_tilt",
    "sqrt_controller",
    "throttle_to_actuator",
    "thrust_curve",
]
