"""Setpoint encoding, telemetry decoding and time mapping against real pymavlink packing / parsing."""

from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from estimators.errors import UserError
from estimators.model import frames
from estimators.model.measurements import Attitude, Imu, LoadAngle, PositionVelocity
from offboard.flight.link import setpoints as spm
from offboard.flight.link.connection import TlogWriter, VehicleClock, normalize_url
from offboard.flight.link.telemetry import TelemetryDecoder, load_angle_from_ned


def _mav(system: int = 1, component: int = 1) -> mavutil.mavlink.MAVLink:
    return mavutil.mavlink.MAVLink(None, srcSystem=system, srcComponent=component)


def _wire(msg, system: int = 1, component: int = 1):
    """Pack with one MAVLink instance and parse with another: the bytes a peer would see."""
    buf = msg.pack(_mav(system, component))
    rx = _mav(255, 191)
    out = rx.parse_buffer(buf)
    assert out is not None and len(out) == 1
    return out[0], buf


def test_attitude_setpoint_round_trip() -> None:
    q = frames.model_quaternion_to_ned(*frames.euler_to_quaternion(0.1, -0.2, 0.7))
    sp = spm.AttitudeTarget(q, 0.3, -0.4, 0.5, 0.61, spm.MASK_ATTITUDE)
    msg = spm.encode(_mav(255, 191), sp, 12.345, 1, 1)
    got, _buf = _wire(msg, 255, 191)
    assert got.get_type() == "SET_ATTITUDE_TARGET" and got.target_system == 1 and got.time_boot_ms == 12345
    back = spm.decode(got)
    assert back.type_mask == 7
    for a, b in zip(back[:1][0], q):
        assert a == pytest.approx(b, abs=1e-7)  # float32 on the wire
    assert back.thrust == pytest.approx(0.61, abs=1e-7) and back.yaw_rate == pytest.approx(0.5, abs=1e-7)


def test_actuator_setpoint_round_trip() -> None:
    sp = spm.ActuatorTarget(0.25, -0.5, 0.125, 0.4)
    got, _ = _wire(spm.encode(_mav(), sp, 2.0, 1, 1))
    assert got.get_type() == "SET_ACTUATOR_CONTROL_TARGET" and got.group_mlx == 0 and got.time_usec == 2_000_000
    assert list(got.controls[:4]) == pytest.approx([0.25, -0.5, 0.125, 0.4], abs=1e-7)
    assert list(got.controls[4:]) == [0.0] * 4
    assert spm.decode(got) == pytest.approx(sp, abs=1e-7)


@pytest.mark.parametrize(
    "bad",
    [
        spm.AttitudeTarget((1.0, 0.0, 0.0, 0.0), math.nan, 0.0, 0.0, 0.5, 7),
        spm.AttitudeTarget((1.0, 0.0, 0.0, math.inf), 0.0, 0.0, 0.0, 0.5, 7),
        spm.AttitudeTarget((0.9, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, 0.5, 7),
        spm.AttitudeTarget((1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, 1.2, 7),
        spm.ActuatorTarget(0.0, math.nan, 0.0, 0.5),
        spm.ActuatorTarget(0.0, 0.0, 1.5, 0.5),
    ],
)
def test_non_finite_or_out_of_range_setpoints_are_refused(bad) -> None:
    with pytest.raises(spm.SetpointError):
        spm.encode(_mav(), bad, 1.0, 1, 1)


def test_attitude_telemetry_to_model_frame() -> None:
    mav = _mav()
    got, _ = _wire(mav.attitude_encode(1500, 0.1, 0.2, -0.3, 0.4, 0.5, 0.6))
    m = TelemetryDecoder(system=1).decode(got)
    assert isinstance(m, Attitude) and m.t == pytest.approx(1.5)
    assert (m.phi, m.theta, m.psi) == pytest.approx((0.1, -0.2, 0.3), abs=1e-7)
    assert (m.p, m.q, m.r) == pytest.approx((0.4, -0.5, -0.6), abs=1e-7)


def test_position_and_imu_telemetry_to_model_frame() -> None:
    mav = _mav()
    dec = TelemetryDecoder(system=1)
    got, _ = _wire(mav.local_position_ned_encode(2000, 1.0, 2.0, -3.0, 0.1, 0.2, -0.3))
    m = dec.decode(got)
    assert isinstance(m, PositionVelocity) and m.t == pytest.approx(2.0)
    assert (m.x, m.y, m.z, m.vx, m.vy, m.vz) == pytest.approx((1.0, -2.0, 3.0, 0.1, -0.2, 0.3), abs=1e-6)
    # level and at rest: PX4 reports specific force (0, 0, -g) in FRD; the model's FLU has +g up
    got, _ = _wire(mav.highres_imu_encode(2_500_000, 0.0, 0.1, -9.81, 0.01, 0.02, 0.03, 0, 0, 0, 0, 0, 0, 0, 0))
    m = dec.decode(got)
    assert isinstance(m, Imu) and m.t == pytest.approx(2.5)
    assert (m.ax, m.ay, m.az) == pytest.approx((0.0, -0.1, 9.81), abs=1e-5)
    assert (m.gx, m.gy, m.gz) == pytest.approx((0.01, -0.02, -0.03), abs=1e-7)
    got, _ = _wire(mav.scaled_imu_encode(3000, 0, 0, -1000, 0, 0, 100, 0, 0, 0))
    m = dec.decode(got)
    assert m.az == pytest.approx(9.80665, rel=1e-6) and m.gz == pytest.approx(-0.1)


def test_odometry_body_velocity_rotated_to_world() -> None:
    # heading 90 deg east (NED yaw +pi/2), moving forward at 1 m/s -> NED velocity east -> model vy = -1
    q = frames.euler_to_quaternion(0.0, 0.0, math.pi / 2)
    got, _ = _wire(
        _mav().odometry_encode(
            4_000_000,
            1,
            12,
            1.0,
            2.0,
            -3.0,
            list(q),
            1.0,
            0.0,
            0.0,
            0,
            0,
            0,
            [math.nan] * 21,
            [math.nan] * 21,
            0,
            0,
            100,
        )
    )
    m = TelemetryDecoder(system=1, use_odometry=True).decode(got)
    assert isinstance(m, PositionVelocity) and m.t == pytest.approx(4.0)
    assert (m.vx, m.vy, m.vz) == pytest.approx((0.0, -1.0, 0.0), abs=1e-6)
    assert TelemetryDecoder(system=1).decode(got) is None  # off by default: the same estimate as LOCAL_POSITION


def test_load_angle_conversion() -> None:
    # load north of the vehicle (x > 0) and east (y > 0): model alpha_y > 0 (+x), alpha_x < 0 (east is -y)
    m = load_angle_from_ned(1.0, 0.2, 0.1)
    assert isinstance(m, LoadAngle) and m.alpha_y == pytest.approx(0.2) and m.alpha_x == pytest.approx(-0.1)
    got, _ = _wire(_mav().debug_vect_encode(b"LOADANG", 5_000_000, 0.05, -0.03, 0.06))
    m = TelemetryDecoder(system=1).decode(got)
    assert m.t == pytest.approx(5.0) and m.alpha_y == pytest.approx(0.05) and m.alpha_x == pytest.approx(0.03)
    got, _ = _wire(_mav().debug_vect_encode(b"OTHER", 5_000_000, 0.05, -0.03, 0.06))
    assert TelemetryDecoder(system=1).decode(got) is None


def test_foreign_system_and_nan_telemetry_refused() -> None:
    got, _ = _wire(_mav(2, 35).attitude_encode(1000, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0), 2, 35)
    dec = TelemetryDecoder(system=1)
    assert dec.decode(got) is None
    got, _ = _wire(_mav().attitude_encode(1000, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert dec.decode(got) is None and dec.counts["refused_nonfinite"] == 1


def test_clock_from_telemetry_takes_least_delayed_sample_and_follows_drift() -> None:
    c = VehicleClock(drift=1e-3)
    for vt, lt in [(1.0, 101.010), (1.1, 101.102), (1.2, 101.230)]:
        c.observe(vt, lt)
    assert c.offset == pytest.approx(100.002, abs=2e-4) and c.source == "telemetry"
    assert c.to_local(2.0) == pytest.approx(2.0 + c.offset) and c.to_vehicle(c.to_local(2.0)) == pytest.approx(2.0)
    # the vehicle clock runs slow: every sample now arrives later; the offset creeps up at most 1e-3 s/s
    c.observe(100.0, 300.0)
    assert 100.003 < c.offset <= 100.0022 + 1e-3 * (300.0 - 101.230) + 1e-12


def test_clock_from_timesync_uses_round_trip_midpoint() -> None:
    c = VehicleClock()
    c.observe(1.0, 101.5)
    c.observe_timesync(5.0, 104.0, 104.004)
    assert c.source == "timesync" and c.offset == pytest.approx(99.002)
    c.observe_timesync(6.0, 105.0, 105.020)  # worse round trip: ignored
    assert c.offset == pytest.approx(99.002)
    c.observe(1.0, 50.0)  # telemetry no longer moves a timesync offset
    assert c.offset == pytest.approx(99.002)


def test_clock_from_timesync_follows_a_vehicle_clock_that_runs_slow() -> None:
    """PX4 SITL's clock runs slower than ours on a loaded machine (3-25 %): the clock fitted through the exchanges
    maps local to vehicle time within a millisecond, where a fixed offset was 0.1 s off within a second."""
    c = VehicleClock()
    rate, v0 = 0.8, 1000.0
    for k in range(12):  # an exchange every 0.5 s, 2 ms round trip
        send = 10.0 + 0.5 * k
        c.observe_timesync(v0 + rate * (send + 0.001 - 10.0), send, send + 0.002)
    now = 10.0 + 0.5 * 11 + 0.4  # between exchanges
    assert c.rate == pytest.approx(rate, rel=1e-6) and c.rate_fitted
    assert c.to_vehicle(now) == pytest.approx(v0 + rate * (now - 10.0), abs=1e-3)
    assert c.to_local(c.to_vehicle(now)) == pytest.approx(now, abs=1e-9)
    fixed = now - c.offset  # what a fixed offset from the last exchange would say
    assert abs(fixed - (v0 + rate * (now - 10.0))) > 0.05


def test_clock_follows_a_rate_change_from_its_latest_exchange_and_says_when_it_is_not_steady() -> None:
    """PX4 SITL's clock rate changes with the machine's load. Anchored at the latest exchange, the clock is off by
    at most the rate's change over the time since that exchange; a line anchored at the exchanges' centroid was
    off by the change over two seconds (a false 101 ms telemetry age in CI). Right after the change the clock
    says it is not steady (the loop then takes no telemetry age from it); once the fit holds again, it is."""
    c = VehicleClock()
    exchanges: list[tuple[float, float]] = []
    v = 1000.0

    def vehicle_at(local: float) -> float:  # the vehicle clock: rate 1 until local 15.75 s, then 0.85
        return v + min(local, 15.75) - 10.0 + 0.85 * max(local - 15.75, 0.0)

    for k in range(13):  # an exchange every 0.5 s, 2 ms round trip; the 13th (local 16 s) sees the new rate
        send = 10.0 + 0.5 * k
        c.observe_timesync(vehicle_at(send + 0.001), send, send + 0.002)
        exchanges.append((send + 0.001, vehicle_at(send + 0.001)))
        assert c.steady == (2 <= k < 12), k
    now = 16.0 + 0.4
    err = abs(c.to_vehicle(now) - vehicle_at(now))
    tail = np.array(exchanges[-8:])
    slope, icpt = np.polyfit(tail[:, 0], tail[:, 1], 1)
    centroid_err = abs(slope * now + icpt - vehicle_at(now))
    assert err < 0.035 and centroid_err > 0.05, (err, centroid_err)
    for k in range(13, 16):  # the new rate holds: the fit restarted at the change is steady again within two exchanges
        send = 10.0 + 0.5 * k
        c.observe_timesync(vehicle_at(send + 0.001), send, send + 0.002)
        assert c.steady == (k >= 14), k
    assert c.rate == pytest.approx(0.85, rel=1e-6)
    assert c.to_vehicle(17.9) == pytest.approx(vehicle_at(17.9), abs=1e-3)


def test_tlog_format_is_readable_by_pymavlink(tmp_path) -> None:
    path = tmp_path / "x.tlog"
    w = TlogWriter(path)
    mav = _mav()
    for i in range(3):
        w.write(mav.attitude_encode(i * 10, 0.1 * i, 0.0, 0.0, 0.0, 0.0, 0.0).pack(mav), 1_700_000_000.0 + i)
    w.close()
    raw = path.read_bytes()
    assert struct.unpack(">Q", raw[:8])[0] == int(1_700_000_000.0 * 1e6) & ~3
    log = mavutil.mavlink_connection(str(path))
    msgs = []
    while (m := log.recv_match(type="ATTITUDE")) is not None:
        msgs.append(m)
    assert [round(m.roll, 6) for m in msgs] == [0.0, 0.1, 0.2]
    assert msgs[2]._timestamp == pytest.approx(1_700_000_002.0, abs=1e-5)


def test_a_setpoint_sent_without_its_log_record_is_on_the_wire_first_and_logged_after(tmp_path) -> None:
    """The loop's tick writes the setpoint (``send(msg, log=False)``) before its tlog record (``log_sent``), so that a
    slow log write never delays it: the datagram is out while the tlog is still empty, and the record then appears
    with the stamp given, readable by pymavlink."""
    import socket

    from offboard.flight.link.connection import MavConnection

    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(5.0)
    conn = MavConnection(f"udpout:127.0.0.1:{peer.getsockname()[1]}", tlog_path=tmp_path / "f.tlog")
    try:
        sp = spm.AttitudeTarget((1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, 0.5, spm.MASK_ATTITUDE)
        buf = conn.send(spm.encode(conn.mav, sp, 1.0, 1, 1), log=False)
        assert peer.recv(300) == buf
        assert (tmp_path / "f.tlog").read_bytes() == b""
        conn.log_sent(buf, 1_700_000_000.0)
        raw = (tmp_path / "f.tlog").read_bytes()
        assert raw == struct.pack(">Q", int(1_700_000_000.0 * 1e6) & ~3) + buf
    finally:
        conn.close()
        peer.close()
    m = mavutil.mavlink_connection(str(tmp_path / "f.tlog")).recv_match(type="SET_ATTITUDE_TARGET")
    assert m is not None and m.thrust == pytest.approx(0.5)


def test_url_forms() -> None:
    assert normalize_url("udpin://0.0.0.0:14540") == ("udpin:0.0.0.0:14540", 57600)
    assert normalize_url("serial:/dev/ttyUSB0:921600") == ("/dev/ttyUSB0", 921600)
    assert normalize_url("/dev/ttyAMA0", 115200) == ("/dev/ttyAMA0", 115200)
    with pytest.raises(UserError):
        normalize_url("udpin:host")
    with pytest.raises(UserError):
        normalize_url("http://x")
    for bad in (("/dev/ttyUSB0", -5), ("/dev/ttyUSB0", 0), ("udpin:127.0.0.1:14540", -5), ("serial:/dev/tty0:0", None)):
        with pytest.raises(UserError, match="baud"):
            normalize_url(*bad)


def test_ardupilot_raw_imu_and_scaled_imu2_are_fallback_imu_sources() -> None:
    """ArduPilot streams RAW_IMU (IMU 1, scaled like SCALED_IMU: mG, mrad/s, time_usec) and SCALED_IMU2 (IMU 2,
    time_boot_ms) by default: both decode to Imu in the model frame, and the filter gets one IMU stream: the
    first higher-ranked message (HIGHRES_IMU) switches the lower ones off."""
    mav = _mav()
    dec = TelemetryDecoder(system=1)
    got, _ = _wire(mav.scaled_imu2_encode(1000, 10, -20, -1000, 100, -200, 300, 0, 0, 0))
    m = dec.decode(got)
    assert isinstance(m, Imu) and m.t == pytest.approx(1.0)
    assert (m.ax, m.ay, m.az) == pytest.approx((0.0980665, 0.196133, 9.80665), rel=1e-6)
    assert (m.gx, m.gy, m.gz) == pytest.approx((0.1, 0.2, -0.3), abs=1e-9)
    got, _ = _wire(mav.raw_imu_encode(2_000_000, 0, 0, -1000, 0, 0, 50, 0, 0, 0))
    m = dec.decode(got)
    assert (
        isinstance(m, Imu)
        and m.t == pytest.approx(2.0)
        and m.az == pytest.approx(9.80665)
        and m.gz == pytest.approx(-0.05)
    )
    # RAW_IMU seen: IMU 2 is now refused
    got, _ = _wire(mav.scaled_imu2_encode(2500, 0, 0, -1000, 0, 0, 0, 0, 0, 0))
    assert dec.decode(got) is None and dec.counts["refused_secondary_imu"] == 1
    got, _ = _wire(mav.highres_imu_encode(3_000_000, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert isinstance(dec.decode(got), Imu)
    got, _ = _wire(mav.raw_imu_encode(3_100_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0))
    assert dec.decode(got) is None and dec.counts["refused_secondary_imu"] == 2
    assert dec.counts["Imu"] == 3
