"""The emulated autopilot's MAVLink messages, each built from one telemetry snapshot
(:class:`~sim_bridge.protocol.telemetry.Snapshot`): ``(mav, snapshot, ctx) -> message``, ``ctx`` the autopilot
(mode, targets, counters). ``BUILDERS`` maps a message name to its builder; ``NEEDS_POSITION``: the messages an
autopilot sends only with a position estimate. Wire conventions (NED / FRD, units, scalings) in
``sim_bridge.protocol.telemetry`` and ``docs/emulator.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from estimators.model.frames import m_s2_to_milli_g
from sim_bridge.protocol.telemetry import Snapshot

_NAN21 = [float("nan")] + [0.0] * 20


def msg_attitude(mav, s: Snapshot, ctx):
    """ATTITUDE: Euler angles (rad, NED/FRD) and body rates (rad/s, FRD)."""
    return mav.attitude_encode(s.t_att_us // 1000, s.roll, s.pitch, s.yaw, s.p, s.qr, s.r)


def msg_attitude_quaternion(mav, s: Snapshot, ctx):
    """ATTITUDE_QUATERNION: q (FRD body to NED), body rates FRD."""
    w, x, y, z = s.q
    return mav.attitude_quaternion_encode(s.t_att_us // 1000, w, x, y, z, s.p, s.qr, s.r, [0.0, 0.0, 0.0, 0.0])


def msg_local_position_ned(mav, s: Snapshot, ctx):
    """LOCAL_POSITION_NED relative to home."""
    # the local frame's z origin is where the estimator started, not the ground (sim_bridge.plant.ekf_error)
    return mav.local_position_ned_encode(s.t_pos_us // 1000, s.pos[0], s.pos[1], s.pos[2] + _z0(ctx), *s.vel)


def msg_odometry(mav, s: Snapshot, ctx):
    """ODOMETRY: pose in LOCAL_NED, velocity and rates in BODY_FRD."""
    vb = _ned_to_body(s.q, s.vel)
    return mav.odometry_encode(
        s.t_pos_us,
        1,
        12,
        s.pos[0],
        s.pos[1],
        s.pos[2] + _z0(ctx),
        list(s.q),
        vb[0],
        vb[1],
        vb[2],
        s.p,
        s.qr,
        s.r,
        _NAN21,
        _NAN21,
        0,
        0,
        100,
    )


def _ned_to_body(q: tuple[float, float, float, float], v: Sequence[float]) -> tuple[float, float, float]:
    """Rotate a NED vector into body FRD with the attitude quaternion q (FRD -> NED)."""
    w, x, y, z = q
    # R^T v with R from q
    r00 = 1 - 2 * (y * y + z * z)
    r01 = 2 * (x * y - w * z)
    r02 = 2 * (x * z + w * y)
    r10 = 2 * (x * y + w * z)
    r11 = 1 - 2 * (x * x + z * z)
    r12 = 2 * (y * z - w * x)
    r20 = 2 * (x * z - w * y)
    r21 = 2 * (y * z + w * x)
    r22 = 1 - 2 * (x * x + y * y)
    a, b, c = v
    return (r00 * a + r10 * b + r20 * c, r01 * a + r11 * b + r21 * c, r02 * a + r12 * b + r22 * c)


def msg_highres_imu(mav, s: Snapshot, ctx):
    """HIGHRES_IMU: specific force (m/s^2, FRD), gyro (rad/s, FRD), pressure altitude."""
    alt = ctx.home.alt - s.pos[2]
    pressure = 1013.25 * (1.0 - 2.25577e-5 * alt) ** 5.25588
    gx, gy, gz = s.gyro
    return mav.highres_imu_encode(
        s.t_imu_us, s.acc[0], s.acc[1], s.acc[2], gx, gy, gz, 0.21, 0.0, 0.42, pressure, 0.0, alt, 25.0, 0x1FFF, 0
    )


def _mg(v: float) -> int:
    return max(-32768, min(32767, round(m_s2_to_milli_g(v))))


def _mrad(v: float) -> int:
    return max(-32768, min(32767, round(v * 1000.0)))


def msg_scaled_imu(mav, s: Snapshot, ctx):
    """SCALED_IMU: accel in mG, gyro in mrad/s (FRD)."""
    gx, gy, gz = s.gyro
    return mav.scaled_imu_encode(
        s.t_imu_us // 1000, _mg(s.acc[0]), _mg(s.acc[1]), _mg(s.acc[2]), _mrad(gx), _mrad(gy), _mrad(gz), 210, 0, 420
    )


def msg_raw_imu(mav, s: Snapshot, ctx):
    """RAW_IMU: as ArduPilot sends it, the same scaling as SCALED_IMU (mG, mrad/s)."""
    gx, gy, gz = s.gyro
    return mav.raw_imu_encode(
        s.t_imu_us, _mg(s.acc[0]), _mg(s.acc[1]), _mg(s.acc[2]), _mrad(gx), _mrad(gy), _mrad(gz), 210, 0, 420
    )


def msg_global_position_int(mav, s: Snapshot, ctx):
    """GLOBAL_POSITION_INT of the vehicle (degE7, mm, cm/s NED, cdeg)."""
    hdg = round(math.degrees(s.yaw) * 100.0) % 36000
    return mav.global_position_int_encode(
        s.t_pos_us // 1000, s.lat, s.lon, s.alt_mm, s.rel_alt_mm, _cms(s.vel[0]), _cms(s.vel[1]), _cms(s.vel[2]), hdg
    )


def _cms(v: float) -> int:
    return max(-32768, min(32767, round(v * 100.0)))


def msg_load_global_position_int(mav, s: Snapshot, ctx):
    """GLOBAL_POSITION_INT of the load, sent by the load's own system (sysid 2)."""
    return mav.global_position_int_encode(
        s.t_us // 1000,
        s.load_lat,
        s.load_lon,
        s.load_alt_mm,
        s.load_rel_alt_mm,
        _cms(s.load_vel[0]),
        _cms(s.load_vel[1]),
        _cms(s.load_vel[2]),
        65535,
    )


def msg_load_attitude(mav, s: Snapshot, ctx):
    """The zero ATTITUDE ArduPilot's slung-payload SITL sends for the payload."""
    return mav.attitude_encode(s.t_us // 1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def msg_debug_vect(mav, s: Snapshot, ctx):
    """Load-angle sensor: DEBUG_VECT "LOADANG" (x north-down angle, y east-down angle, z total, rad)."""
    return mav.debug_vect_encode(b"LOADANG", s.t_load_us, s.swing_n, s.swing_e, s.swing)


def msg_attitude_target(mav, s: Snapshot, ctx):
    """ATTITUDE_TARGET: what the inner loop tracks (q NED, rates FRD, normalized thrust)."""
    q, rates, thrust, mask = ctx.attitude_target_wire()
    return mav.attitude_target_encode(s.t_us // 1000, mask, list(q), rates[0], rates[1], rates[2], thrust)


def msg_vfr_hud(mav, s: Snapshot, ctx):
    """VFR_HUD for ground stations."""
    gs = math.hypot(s.vel[0], s.vel[1])
    hdg = round(math.degrees(s.yaw)) % 360
    return mav.vfr_hud_encode(gs, gs, hdg, round(100 * ctx.throttle_fraction()), ctx.home.alt - s.pos[2], -s.vel[2])


def msg_system_time(mav, s: Snapshot, ctx):
    """SYSTEM_TIME: unix time (µs, from the simulation clock plus the boot epoch) and time_boot_ms."""
    return mav.system_time_encode(ctx.boot_unix_us + s.t_us, s.t_us // 1000)


def _z0(ctx) -> float:
    """NED z of the ground in the estimator's local frame (0 without an EKF error model)."""
    ekf = ctx.ekf
    return 0.0 if ekf is None else ekf.ground_local_z_m


def msg_home_position(mav, s: Snapshot, ctx):
    """HOME_POSITION: where the vehicle booted (on the ground; its local z is the ground's in the local frame)."""
    h = ctx.home
    return mav.home_position_encode(
        round(h.lat * 1e7),
        round(h.lon * 1e7),
        round(h.alt * 1000),
        0.0,
        0.0,
        _z0(ctx),
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
        s.t_us,
    )


def msg_estimator_status(mav, s: Snapshot, ctx):
    """ESTIMATOR_STATUS with the position accuracy the estimate error model reports (``EkfErrorSpec``), None
    (nothing sent) without one; flags as PX4 SITL's EKF2 in flight (895: attitude, velocity, position)."""
    ekf = ctx.ekf
    if ekf is None:
        return None
    h, v = ekf.spec.reported_accuracy_m
    return mav.estimator_status_encode(s.t_us, 895, 0.0, 0.0, 0.0, 0.0, 0.0, math.nan, h, v)


def msg_sys_status(mav, s: Snapshot, ctx):
    """SYS_STATUS with the link counters in the error fields (see docs/emulator.md)."""
    return ctx.sys_status(mav)


def msg_extended_sys_state(mav, s: Snapshot, ctx):
    """EXTENDED_SYS_STATE: landed state (1 on ground, 2 in air, 3 taking off, 4 landing)."""
    return mav.extended_sys_state_encode(0, ctx.landed_state())


def msg_heartbeat(mav, s: Snapshot, ctx):
    """HEARTBEAT of the autopilot."""
    return ctx.heartbeat(mav)


#: stream name -> builder; the name is the MAVLink message name (its id is looked up in the dialect).
BUILDERS = {
    "HEARTBEAT": msg_heartbeat,
    "SYS_STATUS": msg_sys_status,
    "EXTENDED_SYS_STATE": msg_extended_sys_state,
    "ATTITUDE": msg_attitude,
    "ATTITUDE_QUATERNION": msg_attitude_quaternion,
    "HIGHRES_IMU": msg_highres_imu,
    "SCALED_IMU": msg_scaled_imu,
    "RAW_IMU": msg_raw_imu,
    "GLOBAL_POSITION_INT": msg_global_position_int,
    "LOCAL_POSITION_NED": msg_local_position_ned,
    "ODOMETRY": msg_odometry,
    "ATTITUDE_TARGET": msg_attitude_target,
    "VFR_HUD": msg_vfr_hud,
    "DEBUG_VECT": msg_debug_vect,
    "SYSTEM_TIME": msg_system_time,
    "HOME_POSITION": msg_home_position,
    "ESTIMATOR_STATUS": msg_estimator_status,
}


#: messages that need a position estimate (not sent before the estimator is ready, as on PX4 / ArduPilot)
NEEDS_POSITION = frozenset(
    {"GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ODOMETRY", "HOME_POSITION", "ESTIMATOR_STATUS"}
)
