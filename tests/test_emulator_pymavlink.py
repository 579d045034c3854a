"""pymavlink conformance of ``slung emulate`` over real UDP on 127.0.0.1: heartbeat encodings, command acks,
arming and mode-entry rules, offboard / guided failsafes, parameters, message intervals, foreign system ids."""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from emulator_helpers import (
    MAV_CMD_ARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_SET_MESSAGE_INTERVAL,
    Emu,
    attitude_target,
    offboard_then_silence,
)

from estimators.model.vehicle import Vehicle

V = Vehicle()
OFFBOARD = 393216
POSCTL = 196608
AUTO_LOITER = 50593792
AUTO_LAND = 100925440


@pytest.fixture(scope="module")
def px4() -> Iterator[Emu]:
    with Emu("--est-ready", "0.3") as e:
        e.wait_heartbeat()
        e.wait_ready()
        yield e
        e.stop()


def test_px4_heartbeat_identity_and_boot_mode(px4: Emu) -> None:
    hb = px4.wait_heartbeat()
    assert (hb.type, hb.autopilot) == (2, 12)  # QUADROTOR, MAV_AUTOPILOT_PX4
    assert hb.base_mode & 1 and not hb.base_mode & 128  # custom mode enabled, disarmed
    assert hb.custom_mode == AUTO_LOITER
    # 1 Hz
    t0 = time.monotonic()
    px4.wait_heartbeat()
    px4.wait_heartbeat()
    assert 1.5 < time.monotonic() - t0 < 2.6


def test_ardupilot_heartbeat_identity_and_boot_mode() -> None:
    with Emu("--flavor", "ardupilot", "--est-ready", "0.2") as e:
        hb = e.wait_heartbeat()
        assert (hb.type, hb.autopilot, hb.custom_mode) == (2, 3, 0)  # QUADROTOR, ARDUPILOTMEGA, STABILIZE
        e.wait_ready()
        # GUIDED is custom mode 4, LOITER 5, LAND 9
        for num in (4, 5, 9, 2):
            ack = e.command(MAV_CMD_DO_SET_MODE, 1, num)
            assert ack is not None and ack.result == 0
            hb = e.recv("HEARTBEAT", 3.0, cond=lambda m, n=num: m.custom_mode == n)
            assert hb is not None
        ack = e.command(MAV_CMD_DO_SET_MODE, 1, 3)  # AUTO without a mission: not emulated
        assert ack is not None and ack.result == 4  # FAILED, as ArduPilot answers a refused mode change
        e.stop()


def test_commands_are_acknowledged_within_half_a_second(px4: Emu) -> None:
    for cmd, params, expected in [
        (31000, (), 3),  # MAV_CMD_USER_1: unsupported
        (246, (1,), 3),  # reboot: unsupported by the emulator
        (MAV_CMD_SET_MESSAGE_INTERVAL, (30, 10000), 0),
        (MAV_CMD_SET_MESSAGE_INTERVAL, (99999, 10000), 2),  # unknown message: denied
        (MAV_CMD_DO_SET_MODE, (1, 4, 4), 2),  # AUTO.MISSION is not emulated: denied
    ]:
        t0 = time.monotonic()
        ack = px4.command(cmd, *params, timeout=1.0)
        assert ack is not None, cmd
        assert time.monotonic() - t0 < 0.5
        assert ack.result == expected, (cmd, ack.result)
        assert (ack.target_system, ack.target_component) == (255, 190)
    ack = px4.command(512, 148)  # REQUEST_MESSAGE AUTOPILOT_VERSION: ack, then the message
    assert ack.result == 0
    av = px4.recv("AUTOPILOT_VERSION", 2.0)
    assert av is not None and av.capabilities & 8192 and av.capabilities & 64  # MAVLINK2, SET_ATTITUDE_TARGET


def test_ping_and_timesync_are_answered(px4: Emu) -> None:
    px4.mav.ping_send(123456789, 42, 0, 0)
    m = px4.recv("PING", 2.0)
    assert m is not None and (m.time_usec, m.seq, m.target_system, m.target_component) == (123456789, 42, 255, 190)
    px4.mav.timesync_send(0, 987654321)
    m = px4.recv("TIMESYNC", 2.0, cond=lambda m: m.ts1 == 987654321)
    assert m is not None and m.tc1 > 0


def test_commands_for_another_system_are_ignored(px4: Emu) -> None:
    before = px4.recv("SYS_STATUS", 2.0).errors_count2
    for _ in range(3):
        px4.mav.command_long_send(7, 1, MAV_CMD_ARM, 0, 1, 0, 0, 0, 0, 0, 0)
        px4.mav.param_set_send(7, 1, b"COM_OF_LOSS_T", 5.0, 9)
    assert px4.recv("COMMAND_ACK", 1.0) is None
    hb = px4.recv("HEARTBEAT", 2.0)
    assert not hb.base_mode & 128
    after = px4.recv("SYS_STATUS", 2.0, cond=lambda m: m.errors_count2 >= before + 6)
    assert after is not None and after.errors_count2 == before + 6


def _param(e: Emu, name: str) -> object:
    e.mav.param_request_read_send(1, 1, name.encode(), -1)
    return e.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == name)


def test_parameter_protocol_px4(px4: Emu) -> None:
    px4.mav.param_request_list_send(1, 1)
    seen: dict[str, object] = {}
    count = None
    end = time.monotonic() + 5.0
    while time.monotonic() < end and (count is None or len(seen) < count):
        m = px4.recv("PARAM_VALUE", 1.0)
        if m is None:
            break
        count = m.param_count
        seen[m.param_id] = m
    assert count is not None and len(seen) == count
    assert sorted(m.param_index for m in seen.values()) == list(range(count))
    for name in ("COM_OF_LOSS_T", "COM_OBL_RC_ACT", "MPC_THR_HOVER", "EMU_MASS", "EMU_THR_MAX", "EMU_CABLE_LEN"):
        assert name in seen
    assert seen["MPC_THR_HOVER"].param_value == pytest.approx(V.hover_thrust_normalized, abs=1e-4)
    assert seen["EMU_THR_MAX"].param_value == pytest.approx(V.thrust_max)
    # float param set + echo
    px4.mav.param_set_send(1, 1, b"COM_OF_LOSS_T", 0.7, 9)
    m = px4.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == "COM_OF_LOSS_T")
    assert m.param_value == pytest.approx(0.7)
    assert _param(px4, "COM_OF_LOSS_T").param_value == pytest.approx(0.7)
    # PX4 integer params travel bytewise in the float field (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
    m = _param(px4, "COM_OBL_RC_ACT")
    assert m.param_type == 6 and struct.unpack("<i", struct.pack("<f", m.param_value))[0] == 0
    px4.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", 4))[0], 6)
    m = px4.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == "COM_OBL_RC_ACT")
    assert struct.unpack("<i", struct.pack("<f", m.param_value))[0] == 4
    # read-only vehicle constants and out-of-range values are refused (current value echoed)
    px4.mav.param_set_send(1, 1, b"EMU_MASS", 9.0, 9)
    assert px4.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == "EMU_MASS").param_value == pytest.approx(0.5)
    px4.mav.param_set_send(1, 1, b"COM_OF_LOSS_T", 500.0, 9)
    assert px4.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == "COM_OF_LOSS_T").param_value == pytest.approx(0.7)
    # by index
    px4.mav.param_request_read_send(1, 1, b"", seen["MPC_THR_HOVER"].param_index)
    assert px4.recv("PARAM_VALUE", 2.0).param_id == "MPC_THR_HOVER"
    for name, value in (("COM_OF_LOSS_T", 1.0), ("COM_OBL_RC_ACT", 0)):  # restore for the other tests
        wire = value if isinstance(value, float) else struct.unpack("<f", struct.pack("<i", value))[0]
        px4.mav.param_set_send(1, 1, name.encode(), wire, 9 if isinstance(value, float) else 6)
        assert px4.recv("PARAM_VALUE", 2.0, cond=lambda m, n=name: m.param_id == n) is not None


def _rate(e: Emu, name: str, seconds: float) -> float:
    """Messages per simulated second, from the messages' own time stamps."""
    stamps = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        m = e.recv(name, 1.0)
        if m is not None:
            stamps.append(m.time_boot_ms)
    return (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1000.0)


def test_set_message_interval_changes_the_measured_rate(px4: Emu) -> None:
    assert _rate(px4, "ATTITUDE_QUATERNION", 1.0) == pytest.approx(50.0, rel=0.03)
    ack = px4.command(MAV_CMD_SET_MESSAGE_INTERVAL, 31, 5000)  # 200 Hz
    assert ack.result == 0
    assert _rate(px4, "ATTITUDE_QUATERNION", 1.0) == pytest.approx(200.0, rel=0.03)
    assert px4.command(MAV_CMD_SET_MESSAGE_INTERVAL, 31, -1).result == 0  # off
    time.sleep(0.1)
    assert px4.recv("ATTITUDE_QUATERNION", 0.5) is None
    assert px4.command(MAV_CMD_SET_MESSAGE_INTERVAL, 31, 0).result == 0  # back to the default
    assert _rate(px4, "ATTITUDE_QUATERNION", 1.0) == pytest.approx(50.0, rel=0.03)


def test_load_is_a_second_system_streaming_global_position_int(px4: Emu) -> None:
    hb = px4.recv("HEARTBEAT", 3.0, sysid=2)
    assert hb is not None and hb.autopilot == 8  # MAV_AUTOPILOT_INVALID, like ArduPilot's payload SITL
    veh = px4.recv("GLOBAL_POSITION_INT", 2.0)
    stamps = []
    load = None
    end = time.monotonic() + 1.05
    while time.monotonic() < end:
        m = px4.recv("GLOBAL_POSITION_INT", 1.0, sysid=2)
        if m is not None:
            stamps.append(m.time_boot_ms)
            load = m
    assert (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1000.0) == pytest.approx(10.0, rel=0.05)
    assert veh.relative_alt - load.relative_alt == pytest.approx(V.cable_length * 1000, abs=2)  # hangs below
    assert (load.lat, load.lon) == (veh.lat, veh.lon)


def test_arming_refused_until_the_estimator_is_ready() -> None:
    with Emu("--est-ready", "2.0") as e:
        e.wait_heartbeat()
        ack = e.command(MAV_CMD_ARM, 1, 21196)  # PX4 still runs the checks for external force-arm
        assert ack is not None and ack.result == 1  # TEMPORARILY_REJECTED
        assert any("Preflight Fail" in t for t in e.texts)
        assert e.recv("LOCAL_POSITION_NED", 0.2) is None  # no position estimate yet
        e.wait_ready(5.0)
        ack = e.command(MAV_CMD_ARM, 1, 0)
        assert ack.result == 0
        hb = e.recv("HEARTBEAT", 2.0, cond=lambda m: m.base_mode & 128)
        assert hb is not None
        assert e.command(MAV_CMD_ARM, 0, 0).result == 0  # disarm on the ground
        assert e.command(MAV_CMD_ARM, 2, 0).result == 3  # neither arm nor disarm: UNSUPPORTED, as PX4 answers
        assert any("Unsupported ARM_DISARM param" in t for t in e.texts)
        e.stop()


def test_px4_offboard_entry_rules_and_loss_failsafe() -> None:
    with Emu("--est-ready", "0.2") as e:
        e.wait_heartbeat()
        e.wait_ready()
        # no setpoint stream: refused
        ack = e.command(MAV_CMD_DO_SET_MODE, 1, 6, 0)
        assert ack.result == 1
        assert any("Offboard" in t for t in e.texts)
        # a setpoint without thrust is no proof of life (PX4 #27627)
        e.mav.set_attitude_target_send(0, 1, 1, 7 | 64, [1, 0, 0, 0], 0, 0, 0, 0.0)
        assert e.command(MAV_CMD_DO_SET_MODE, 1, 6, 0).result == 1
        # stream, arm, switch, climb
        hover = V.hover_thrust_normalized
        t_end = time.monotonic() + 0.3
        while time.monotonic() < t_end:
            attitude_target(e.mav, 0, 0, 0, 0.0)
            time.sleep(0.02)
        assert e.command(MAV_CMD_ARM, 1, 0).result == 0
        attitude_target(e.mav, 0, 0, 0, hover + 0.1)
        assert e.command(MAV_CMD_DO_SET_MODE, 1, 6, 0).result == 0
        assert e.recv("HEARTBEAT", 2.0, cond=lambda m: m.custom_mode == OFFBOARD and m.base_mode & 128)
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            attitude_target(e.mav, 0, 0, 0, hover + 0.1)
            time.sleep(0.02)
        z_climb = e.latest("LOCAL_POSITION_NED").z
        assert z_climb < -0.5  # climbed (NED z up is negative)
        # stop streaming: after COM_OF_LOSS_T (1 s) the default action COM_OBL_RC_ACT = 0 -> Position
        t_last = time.monotonic()
        hb = e.recv("HEARTBEAT", 4.0, cond=lambda m: m.custom_mode != OFFBOARD)
        assert hb is not None and hb.custom_mode == POSCTL
        assert 0.9 < time.monotonic() - t_last < 2.3  # 1 s timeout + up to 1 s heartbeat period
        e.recv("HEARTBEAT", 2.0)
        assert any("offboard signal lost" in t for t in e.texts)
        # Position mode brakes and holds
        time.sleep(3.0)
        z1 = e.latest("LOCAL_POSITION_NED").z
        time.sleep(1.0)
        z2 = e.latest("LOCAL_POSITION_NED").z
        assert abs(z2 - z1) < 0.15 and z2 < -0.5
        # disarming in the air is refused without force, accepted with 21196
        assert e.command(MAV_CMD_ARM, 0, 0).result == 1
        assert e.command(MAV_CMD_ARM, 0, 21196).result == 0
        e.stop()


def test_px4_offboard_loss_action_land() -> None:
    with Emu("--est-ready", "0.2", "--lockstep") as e:
        t_stop = offboard_then_silence(e, 4)
        hb = e.recv("HEARTBEAT", 5.0, cond=lambda m: m.custom_mode == AUTO_LAND)
        assert hb is not None
        m = e.recv("EXTENDED_SYS_STATE", 2.0)
        assert m.landed_state == 4  # LANDING
        e.stop()
        assert e.summary["counters"]["failsafes"] == 1
        switch = next(t for t, mode in e.summary["modes"] if mode == "AUTO.LAND")
        assert switch * 1000 - t_stop == pytest.approx(500, abs=15)  # COM_OF_LOSS_T in simulation time


def _climb_rate(e: Emu, thrust: float, seconds: float, period_s: float = 0.01) -> float:
    """Lockstep: stream attitude setpoints with ``thrust`` for ``seconds``; mean climb rate (m/s, up)."""
    z0 = t0 = None
    z = t = 0.0
    for _ in range(int(seconds / period_s)):
        attitude_target(e.mav, 0, 0, 0, thrust)
        while True:
            m = e.recv(["LOCAL_POSITION_NED", "SYSTEM_TIME"], 2.0)
            if m.get_type() == "LOCAL_POSITION_NED":
                z, t = -m.z, m.time_boot_ms / 1000.0
                if z0 is None:
                    z0, t0 = z, t
            else:
                break
    return (z - z0) / (t - t0)


def test_ardupilot_guided_thrust_semantics_and_timeout() -> None:
    with Emu("--flavor", "ardupilot", "--est-ready", "0.2", "--lockstep") as e:
        e.wait_heartbeat()
        e.wait_ready()
        e.command(MAV_CMD_SET_MESSAGE_INTERVAL, 32, 10000)
        assert e.command(MAV_CMD_DO_SET_MODE, 1, 4).result == 0  # GUIDED
        assert e.command(MAV_CMD_ARM, 1, 0).result == 0
        # default: thrust is a climb-rate command; 0.75 -> (0.75 - 0.5) * 2 * WPNAV_SPEED_UP (2.5 m/s)
        _climb_rate(e, 0.75, 2.0)
        assert _climb_rate(e, 0.75, 1.0) == pytest.approx(1.25, abs=0.1)
        _climb_rate(e, 0.5, 1.5)
        assert _climb_rate(e, 0.5, 1.0) == pytest.approx(0.0, abs=0.05)
        # GUID_OPTIONS bit 3: thrust is throttle; hover throttle holds roughly, more climbs faster and faster
        e.mav.param_set_send(1, 1, b"GUID_OPTIONS", 8.0, 6)
        assert e.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == "GUID_OPTIONS").param_value == 8.0
        hover = V.hover_thrust_normalized
        assert abs(_climb_rate(e, hover, 0.5)) < 0.3
        r1 = _climb_rate(e, hover + 0.1, 0.5)
        r2 = _climb_rate(e, hover + 0.1, 0.5)
        assert r2 > r1 > 0.1
        # GUID_TIMEOUT: stop streaming; after 3 s the vehicle levels and holds its altitude
        e.mav.param_set_send(1, 1, b"GUID_TIMEOUT", 0.5, 9)
        assert e.recv("PARAM_VALUE", 2.0, cond=lambda m: m.param_id == "GUID_TIMEOUT") is not None
        st = e.recv("STATUSTEXT", 3.0, cond=lambda m: "timed out" in m.text)
        assert st is not None
        time.sleep(1.5)  # levels and stops the climb (free-running in real time: no setpoints)
        z1 = e.latest("LOCAL_POSITION_NED").z
        time.sleep(1.0)
        m = e.latest("LOCAL_POSITION_NED")
        assert abs(m.z - z1) < 0.2 and abs(m.vz) < 0.2
        hb = e.recv("HEARTBEAT", 2.0)
        assert hb.custom_mode == 4  # still GUIDED
        e.stop()


def test_arming_refused_in_land_mode_ardupilot() -> None:
    with Emu("--flavor", "ardupilot", "--est-ready", "0.2") as e:
        e.wait_heartbeat()
        e.wait_ready()
        assert e.command(MAV_CMD_DO_SET_MODE, 1, 9).result == 0  # LAND
        ack = e.command(MAV_CMD_ARM, 1, 0)
        assert ack.result == 4  # FAILED
        assert any("not armable" in t for t in e.texts)
        assert e.command(MAV_CMD_ARM, 1, 2989).result == 0  # ArduPilot's force-arm magic skips the checks
        assert e.command(MAV_CMD_ARM, 3, 0).result == 3  # neither arm nor disarm: UNSUPPORTED
        e.stop()


def test_nan_and_malformed_setpoints_are_rejected_and_counted() -> None:
    with Emu("--est-ready", "0.2") as e:
        e.wait_heartbeat()
        e.wait_ready()
        e.mav.set_attitude_target_send(0, 1, 1, 7, [math.nan, 0, 0, 0], 0, 0, 0, 0.5)
        e.mav.set_attitude_target_send(0, 1, 1, 7, [0, 0, 0, 0], 0, 0, 0, 0.5)
        e.mav.set_attitude_target_send(0, 1, 1, 128, [1, 0, 0, 0], math.inf, 0, 0, 0.5)
        e.mav.set_position_target_local_ned_send(0, 1, 1, 1, 0b110111111000, math.nan, 0, -2, 0, 0, 0, 0, 0, 0, 0, 0)
        assert e.command(MAV_CMD_DO_SET_MODE, 1, 6, 0).result == 1  # none of them is a proof of life
        m = e.recv("SYS_STATUS", 2.0, cond=lambda m: m.errors_count4 >= 4)
        assert m is not None and m.errors_count4 == 4
        e.stop()
        assert e.summary["link"]["rx"]["malformed"] == 4


def _lockstep_steps(e: Emu, send: Callable[[], None], n: int) -> Any:
    """Send ``n`` setpoints in lockstep, reading to each end-of-step marker; the last LOCAL_POSITION_NED."""
    pos = None
    for _ in range(n):
        send()
        while True:
            m = e.recv(["LOCAL_POSITION_NED", "SYSTEM_TIME"], 2.0)
            assert m is not None
            if m.get_type() == "SYSTEM_TIME":
                break
            pos = m
    return pos


def test_px4_position_and_actuator_setpoints_in_offboard() -> None:
    with Emu("--est-ready", "0.2", "--lockstep") as e:
        e.wait_heartbeat()
        e.wait_ready()
        e.command(MAV_CMD_SET_MESSAGE_INTERVAL, 32, 10000)
        mask_pos = 0b100111111000  # position and yaw; velocity, acceleration, yaw rate ignored

        def pos_sp() -> None:
            e.mav.set_position_target_local_ned_send(0, 1, 1, 1, mask_pos, 1.0, -0.5, -2.0, 0, 0, 0, 0, 0, 0, 0.5, 0)

        _lockstep_steps(e, pos_sp, 5)
        assert e.command(MAV_CMD_ARM, 1, 0).result == 0
        assert e.command(MAV_CMD_DO_SET_MODE, 1, 6, 0).result == 0
        p = _lockstep_steps(e, pos_sp, 1000)  # 10 s
        assert (p.x, p.y, p.z) == pytest.approx((1.0, -0.5, -2.0), abs=0.1)
        assert e.latest("ATTITUDE").yaw == pytest.approx(0.5, abs=0.03)  # NED yaw: 0.5 rad east of north
        # PX4 <= v1.13 actuator controls: thrust above hover with zero torques climbs straight up
        hover = V.hover_thrust_normalized

        def act(thrust: float, roll: float = 0.0) -> Callable[[], None]:
            return lambda: e.mav.set_actuator_control_target_send(0, 0, 1, 1, [roll, 0, 0, thrust, 0, 0, 0, 0])

        p0 = _lockstep_steps(e, act(hover + 0.05), 1)
        p1 = _lockstep_steps(e, act(hover + 0.05), 100)
        assert p1.z < p0.z - 0.1 and abs(p1.vx) < 0.3 and abs(p1.vy) < 0.3
        # a positive roll control rolls right (FRD): the roll rate in ATTITUDE becomes positive
        # (relative to the roll before: the free climb with zero torques need not stay exactly level)
        e.command(MAV_CMD_SET_MESSAGE_INTERVAL, 30, 10000)
        _lockstep_steps(e, act(hover), 1)
        att0 = e.recv("ATTITUDE", 2.0)
        _lockstep_steps(e, act(hover, 0.2), 5)
        att = e.recv("ATTITUDE", 2.0)
        assert att.rollspeed > 0.05 and att.roll > att0.roll
        e.stop()
        assert e.summary["counters"]["setpoints_rejected"] == 0


def test_bad_command_line_is_a_one_line_user_error(capsys: pytest.CaptureFixture[str]) -> None:
    from offboard.cli import main

    for argv in (
        ["emulate", "--loss-in", "2"],
        ["emulate", "--signing-key", "abc"],
        ["emulate", "--mavlink", "tcp:127.0.0.1:5760"],
        ["emulate", "--lockstep-period", "0"],
        ["emulate", "--vehicle", "/nonexistent/vehicle.toml"],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("slung emulate: error:") and "\n" not in err, err


def test_px4_every_mode_has_its_heartbeat_encoding() -> None:
    from sim_bridge.modes.flavors import PX4_MODES

    with Emu("--est-ready", "0.2") as e:
        e.wait_heartbeat()
        e.wait_ready()
        for mode in PX4_MODES:
            if mode.name == "OFFBOARD":
                continue
            main, sub = (mode.custom_mode >> 16) & 0xFF, (mode.custom_mode >> 24) & 0xFF
            if mode.name == "AUTO.TAKEOFF":  # through COMMAND_INT this time (disarmed: stays in take-off)
                e.drain()
                e.mav.command_int_send(1, 1, 0, 176, 0, 0, 1, main, sub, 0, 0, 0, 0)
                ack = e.recv("COMMAND_ACK", 1.0, cond=lambda m: m.command == 176)
            else:
                ack = e.command(MAV_CMD_DO_SET_MODE, 1, main, sub)
            assert ack is not None and ack.result == 0, mode.name
            e.command(512, 0)  # REQUEST_MESSAGE HEARTBEAT: answered at once
            hb = e.recv("HEARTBEAT", 2.0)
            assert hb.custom_mode == mode.custom_mode, mode.name
            assert hb.base_mode == mode.base_flags, mode.name
        # the legacy SET_MODE message: acknowledged as DO_SET_MODE
        e.mav.set_mode_send(1, 1, 196608)
        assert e.recv("COMMAND_ACK", 1.0, cond=lambda m: m.command == 176).result == 0
        e.command(512, 0)
        assert e.recv("HEARTBEAT", 2.0).custom_mode == 196608
        e.stop()


@pytest.mark.parametrize(("flavor", "target"), [("px4", 2.5), ("ardupilot", 1.5)])
def test_takeoff_ends_holding_the_target_altitude(flavor: str, target: float) -> None:
    """PX4's take-off (to MIS_TAKEOFF_ALT, 2.5 m) hands over to Hold at the take-off altitude, ArduPilot's GUIDED
    take-off (param7 above home) keeps its target: not 0.1 m below it, where the climb entered the acceptance band."""
    with Emu("--flavor", flavor, "--est-ready", "0.2") as e:
        e.wait_heartbeat()
        e.wait_ready()
        if flavor == "px4":
            assert e.command(MAV_CMD_ARM, 1, 0).result == 0
            assert e.command(22, 0, 0, 0, 0, 0, 0, float("nan")).result == 0
            assert e.recv("HEARTBEAT", 10.0, cond=lambda m: m.custom_mode == AUTO_LOITER and m.base_mode & 128)
        else:
            assert e.command(MAV_CMD_DO_SET_MODE, 1, 4).result == 0  # GUIDED
            assert e.command(MAV_CMD_ARM, 1, 0).result == 0
            assert e.command(22, 0, 0, 0, 0, 0, 0, target).result == 0
            assert e.recv("LOCAL_POSITION_NED", 10.0, cond=lambda m: -m.z > target - 0.1) is not None
        time.sleep(3.0)  # settle in the hold
        e.drain()  # what arrived while sleeping
        zs = []
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            m = e.recv("LOCAL_POSITION_NED", 0.5)
            if m is not None:
                zs.append(-m.z)
        e.stop()
    assert len(zs) >= 3  # LOCAL_POSITION_NED streams at 50 Hz (PX4) / 5 Hz (ArduPilot)
    assert abs(sum(zs) / len(zs) - target) < 0.03, (sum(zs) / len(zs), target)
