"""MAVLink telemetry -> the estimator's measurement records (``estimators.model.measurements``), model frame.

Every NED / FRD quantity is converted with ``estimators.model.frames`` (nothing is re-implemented here). Record time
``t`` is the VEHICLE's sample time in seconds since its boot, from the message's own ``time_boot_ms`` or
``time_usec`` (the filters place measurements by sample time; ``offboard.flight.link.connection.VehicleClock`` maps it
to local time for staleness and latency figures).

Decoded messages:

- ATTITUDE -> :class:`Attitude` (Euler angles and body rates);
- ATTITUDE_QUATERNION -> :class:`Attitude` (only when ``use_attitude_quaternion``: the two carry the same
  estimate, and a filter fed both would count it twice);
- LOCAL_POSITION_NED -> :class:`PositionVelocity`;
- ODOMETRY (frame LOCAL_NED; velocity in LOCAL_NED or BODY_FRD, rotated to the world with the message's own
  quaternion) -> :class:`PositionVelocity` (only when ``use_odometry``, for the same reason);
- HIGHRES_IMU (m/s^2, rad/s) and SCALED_IMU (mg, mrad/s) -> :class:`Imu` (specific force: +g on body z up at rest);
  RAW_IMU (ArduPilot's first IMU, which it scales like SCALED_IMU: mG, mrad/s, ``time_usec``) and SCALED_IMU2
  (its second IMU: mG, mrad/s, ``time_boot_ms``), which ArduPilot streams by default, are FALLBACK sources: the
  filter must see one IMU stream, not the same motion twice, so the decoder ranks the IMU messages (HIGHRES_IMU
  and SCALED_IMU first, then RAW_IMU, then SCALED_IMU2) and, once it has seen a message of a rank, refuses those
  of lower ranks (counted as ``refused_secondary_imu``);
- ESTIMATOR_STATUS (pos_horiz_accuracy, pos_vert_accuracy, m) -> :class:`ReportedAccuracy`, the estimator's own
  accuracy; GPS_RAW_INT (h_acc, v_acc, mm; fix 3D or better) -> :class:`ReportedAccuracy` only until the first
  ESTIMATOR_STATUS (the receiver's accuracy stands in for the estimator's where the estimator reports none;
  counted as ``refused_secondary_accuracy`` after). GPS_RAW_INT's eph / epv are dilutions of precision (HDOP x 100),
  not lengths, and are not used. The GPS record is stamped with the newest vehicle time decoded so far (its
  ``time_usec`` may be UNIX time, or 0 as PX4 SITL sends);
- DEBUG_VECT named ``LOADANG`` (the emulator's cable-angle sensor, ``docs/emulator.md``): x = swing in the
  North-Down plane ``atan2(r_N, r_D)``, y = in the East-Down plane ``atan2(r_E, r_D)`` -> :class:`LoadAngle`,
  converted by rebuilding the cable direction ``r_ned ~ (tan x, tan y, 1)`` and taking the model frame's
  planar angles of ``frames.ned_to_model_vector(r_ned)`` (so ``alpha_y = x`` and ``alpha_x = -y``).

Messages from other systems (e.g. a payload reporting as its own system) and non-finite values are refused
(counted in :attr:`TelemetryDecoder.counts`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from estimators.model.frames import (
    frd_to_model_body,
    milli_g_to_m_s2,
    ned_euler_to_model,
    ned_quaternion_to_model,
    ned_to_model_vector,
    quaternion_to_euler,
)
from estimators.model.measurements import (
    Attitude,
    Imu,
    LoadAngle,
    Measurement,
    PositionVelocity,
    ReportedAccuracy,
    is_finite,
)

LOAD_ANGLE_NAME = "LOADANG"
MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
#: IMU message -> rank (lower is preferred; see the module docstring)
IMU_RANK: dict[str, int] = {"HIGHRES_IMU": 0, "SCALED_IMU": 0, "RAW_IMU": 1, "SCALED_IMU2": 2}

#: message name -> message id, for SET_MESSAGE_INTERVAL requests
MESSAGE_IDS: dict[str, int] = {
    "ATTITUDE": 30,
    "ATTITUDE_QUATERNION": 31,
    "ATTITUDE_TARGET": 83,
    "LOCAL_POSITION_NED": 32,
    "HIGHRES_IMU": 105,
    "SCALED_IMU": 26,
    "RAW_IMU": 27,
    "SCALED_IMU2": 116,
    "ODOMETRY": 331,
    "DEBUG_VECT": 250,
    "TIMESYNC": 111,
    "ESTIMATOR_STATUS": 230,
    "GPS_RAW_INT": 24,
}
#: GPS_RAW_INT fix types from 3D on (GPS_FIX_TYPE_3D_FIX = 3)
GPS_FIX_3D = 3


def _vehicle_time_ms(ms: int) -> float:
    return ms * 1e-3


def _milli_g_acceleration(msg: Any) -> tuple[float, float, float]:
    """A SCALED_IMU / RAW_IMU message's accelerations (milli-g, FRD) -> model body FLU, m/s^2."""
    return frd_to_model_body(milli_g_to_m_s2(msg.xacc), milli_g_to_m_s2(msg.yacc), milli_g_to_m_s2(msg.zacc))


def _vehicle_time_us(us: int) -> float:
    return us * 1e-6


def plausible_load_angles(swing_n: float, swing_e: float) -> bool:
    """Whether a LOADANG sample's plane angles (rad) can be a hanging cable's: finite and below 1.5 rad (86 deg)
    in each plane; a sample that is not is refused, wherever it is read (the live link, a tlog, a ULog)."""
    return math.isfinite(swing_n) and math.isfinite(swing_e) and abs(swing_n) < 1.5 and abs(swing_e) < 1.5


def load_angle_from_ned(t: float, swing_n: float, swing_e: float) -> LoadAngle:
    """LoadAngle (model frame) from the North-Down and East-Down plane swing angles (rad)."""
    rx, ry, rz = ned_to_model_vector(math.tan(swing_n), math.tan(swing_e), 1.0)
    return LoadAngle(t, math.atan2(ry, -rz), math.atan2(rx, -rz))


def _rotate_body_to_world(
    q: tuple[float, float, float, float], v: tuple[float, float, float]
) -> tuple[float, float, float]:
    """v_world = R(q) v_body for a unit quaternion (w, x, y, z) (frame-agnostic)."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    a, b, c = v
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return (r00 * a + r01 * b + r02 * c, r10 * a + r11 * b + r12 * c, r20 * a + r21 * b + r22 * c)


@dataclass
class TelemetryDecoder:
    """Stateless apart from counters. ``system``: the autopilot's system id (others are ignored, None = any)."""

    system: int | None = None
    use_attitude_quaternion: bool = False
    use_odometry: bool = False
    counts: dict[str, int] = field(default_factory=dict)
    #: best (lowest) IMU rank seen so far (``IMU_RANK``); 99 before any IMU message
    imu_rank: int = 99
    #: an ESTIMATOR_STATUS has been seen: GPS_RAW_INT's accuracy is no longer used
    estimator_accuracy_seen: bool = False
    #: the newest sample time decoded (s of vehicle time), the stamp of GPS_RAW_INT's accuracy
    newest_t: float = 0.0

    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def decode(self, msg: Any) -> Measurement | None:
        """The measurement a pymavlink message carries, or None (not telemetry we use / refused)."""
        kind = msg.get_type()
        if self.system is not None and msg.get_srcSystem() != self.system:
            return None
        m: Measurement | None
        if kind == "ATTITUDE":
            if not math.isfinite(msg.roll + msg.pitch + msg.yaw + msg.rollspeed + msg.pitchspeed + msg.yawspeed):
                self._count("refused_nonfinite")  # refused before any conversion (the yaw wrap cannot take inf)
                return None
            phi, theta, psi = ned_euler_to_model(msg.roll, msg.pitch, msg.yaw)
            p, q, r = frd_to_model_body(msg.rollspeed, msg.pitchspeed, msg.yawspeed)
            m = Attitude(_vehicle_time_ms(msg.time_boot_ms), phi, theta, psi, p, q, r)
        elif kind == "ATTITUDE_QUATERNION" and self.use_attitude_quaternion:
            try:
                phi, theta, psi = quaternion_to_euler(*ned_quaternion_to_model(msg.q1, msg.q2, msg.q3, msg.q4))
            except ValueError:
                self._count("refused_nonfinite")
                return None
            p, q, r = frd_to_model_body(msg.rollspeed, msg.pitchspeed, msg.yawspeed)
            m = Attitude(_vehicle_time_ms(msg.time_boot_ms), phi, theta, psi, p, q, r)
        elif kind == "LOCAL_POSITION_NED":
            x, y, z = ned_to_model_vector(msg.x, msg.y, msg.z)
            vx, vy, vz = ned_to_model_vector(msg.vx, msg.vy, msg.vz)
            m = PositionVelocity(_vehicle_time_ms(msg.time_boot_ms), x, y, z, vx, vy, vz)
        elif kind == "ODOMETRY" and self.use_odometry:
            if msg.frame_id != MAV_FRAME_LOCAL_NED:
                self._count("refused_frame")
                return None
            v_ned = (msg.vx, msg.vy, msg.vz)
            if msg.child_frame_id == MAV_FRAME_BODY_FRD:
                if not all(math.isfinite(a) for a in msg.q) or sum(a * a for a in msg.q) < 0.5:
                    self._count("refused_nonfinite")
                    return None
                v_ned = _rotate_body_to_world(tuple(msg.q), v_ned)  # type: ignore[arg-type]
            x, y, z = ned_to_model_vector(msg.x, msg.y, msg.z)
            vx, vy, vz = ned_to_model_vector(*v_ned)
            m = PositionVelocity(_vehicle_time_us(msg.time_usec), x, y, z, vx, vy, vz)
        elif kind in IMU_RANK and IMU_RANK[kind] > self.imu_rank:
            self._count("refused_secondary_imu")
            return None
        elif kind == "HIGHRES_IMU":
            ax, ay, az = frd_to_model_body(msg.xacc, msg.yacc, msg.zacc)
            gx, gy, gz = frd_to_model_body(msg.xgyro, msg.ygyro, msg.zgyro)
            m = Imu(_vehicle_time_us(msg.time_usec), ax, ay, az, gx, gy, gz)
        elif kind == "SCALED_IMU":
            ax, ay, az = _milli_g_acceleration(msg)
            gx, gy, gz = frd_to_model_body(msg.xgyro * 1e-3, msg.ygyro * 1e-3, msg.zgyro * 1e-3)
            m = Imu(_vehicle_time_ms(msg.time_boot_ms), ax, ay, az, gx, gy, gz)
        elif kind in ("RAW_IMU", "SCALED_IMU2"):
            ax, ay, az = _milli_g_acceleration(msg)
            gx, gy, gz = frd_to_model_body(msg.xgyro * 1e-3, msg.ygyro * 1e-3, msg.zgyro * 1e-3)
            t = _vehicle_time_us(msg.time_usec) if kind == "RAW_IMU" else _vehicle_time_ms(msg.time_boot_ms)
            m = Imu(t, ax, ay, az, gx, gy, gz)
        elif kind == "ESTIMATOR_STATUS":
            h, v = msg.pos_horiz_accuracy, msg.pos_vert_accuracy
            if not (math.isfinite(h) and math.isfinite(v) and h > 0.0 and v > 0.0):
                self._count("refused_nonfinite")
                return None
            self.estimator_accuracy_seen = True
            m = ReportedAccuracy(_vehicle_time_us(msg.time_usec), float(h), float(v))
        elif kind == "GPS_RAW_INT":
            h_mm, v_mm = getattr(msg, "h_acc", 0), getattr(msg, "v_acc", 0)  # MAVLink 2 extensions, 0 = unknown
            if self.estimator_accuracy_seen:
                self._count("refused_secondary_accuracy")
                return None
            if msg.fix_type < GPS_FIX_3D or not (h_mm > 0 and v_mm > 0):
                return None
            m = ReportedAccuracy(self.newest_t, h_mm * 1e-3, v_mm * 1e-3)
        elif kind == "DEBUG_VECT":
            name = msg.name.decode("ascii", "replace") if isinstance(msg.name, bytes) else str(msg.name)
            if name.rstrip("\x00") != LOAD_ANGLE_NAME:
                return None
            if not plausible_load_angles(msg.x, msg.y):
                self._count("refused_nonfinite")
                return None
            m = load_angle_from_ned(_vehicle_time_us(msg.time_usec), msg.x, msg.y)
        else:
            return None
        if not (math.isfinite(sum(m)) or is_finite(m)):  # a finite sum proves every field finite (else look)
            self._count("refused_nonfinite")
            return None
        rank = IMU_RANK.get(kind)
        if rank is not None:
            self.imu_rank = rank
        if m.t > self.newest_t and not isinstance(m, ReportedAccuracy):
            self.newest_t = m.t
        name = type(m).__name__
        counts = self.counts
        counts[name] = counts.get(name, 0) + 1
        return m


__all__ = [
    "IMU_RANK",
    "LOAD_ANGLE_NAME",
    "MESSAGE_IDS",
    "TelemetryDecoder",
    "load_angle_from_ned",
    "plausible_load_angles",
]
