"""The emulated autopilot's MAVLink behaviour (PX4 or ArduPilot Copter flavour).

Heartbeat, modes and their encodings, arming rules with reasons, commands with COMMAND_ACK, the parameter
protocol, telemetry streams with SET_MESSAGE_INTERVAL, offboard / guided setpoints and their failsafes,
STATUSTEXT, signing checks and the link counters. The physics lives in ``sim_bridge/dynamics.py`` and the
inner loops in ``sim_bridge/airframe.py``; the clock in ``sim_bridge/emulator.py`` calls

- :meth:`Autopilot.handle_datagram` for each received datagram (returns how many setpoints it accepted, which
  the lockstep clock turns into steps),
- :meth:`Autopilot.control` once per plant step (returns the motors' thrust and torques),
- :meth:`Autopilot.after_step` once per plant step (telemetry that came due, timers, failsafes).

Frames: setpoints arrive in NED / FRD and are converted to the model frame (NWU / FLU) with
``estimators.frames`` only; everything inside is model frame, SI.
"""

from __future__ import annotations

import logging
import math
import os
import struct
import time
from collections.abc import Sequence
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as _apm
from pymavlink.dialects.v20 import common as _common

from estimators.frames import (
    euler_to_quaternion,
    frd_to_model_body,
    model_body_to_frd,
    model_quaternion_to_ned,
    ned_euler_to_model,
    ned_quaternion_to_model,
    ned_to_model_vector,
)
from estimators.vehicle import Vehicle
from sim_bridge.airframe import (
    AttitudeController,
    Mixer,
    PositionController,
    angle_boost,
    ardupilot_climb_rate,
    ardupilot_throttle_newtons,
    body_rates,
    px4_thrust_newtons,
)
from sim_bridge.dynamics import plant_params
from sim_bridge.flavors import INT8, INT16, INT32, SAFETY_ARMED, Flavor, Mode, make_flavor
from sim_bridge.link import Link
from sim_bridge.telemetry import (
    BUILDERS,
    NEEDS_POSITION,
    Home,
    TelemetrySource,
    msg_load_attitude,
    msg_load_global_position_int,
)

log = logging.getLogger(__name__)

# MAV_RESULT
ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4
# MAV_SEVERITY
EMERGENCY, ALERT, CRITICAL, ERROR, WARNING, NOTICE, INFO = 0, 1, 2, 3, 4, 5, 6

PX4_FORCE = 21196  # MAVLink spec force value (arm/disarm); ArduPilot uses it for force-disarm
AP_FORCE_ARM = 2989  # ArduPilot's force-arm magic

SETPOINT_MSGS = frozenset({"SET_ATTITUDE_TARGET", "SET_POSITION_TARGET_LOCAL_NED", "SET_ACTUATOR_CONTROL_TARGET"})
SETPOINT_IDS = frozenset({82, 84, 139})

#: PX4 COM_OBL_RC_ACT -> mode name (6 Terminate and 7 Disarm are handled separately)
PX4_OBL_ACTIONS = {0: "POSCTL", 1: "ALTCTL", 2: "STABILIZED", 3: "AUTO.RTL", 4: "AUTO.LAND", 5: "AUTO.LOITER"}

LOAD_COMPID = 35  # MAV_COMP_ID_USER11, as ArduPilot's slung-payload SITL


def _finite(*vals: float) -> bool:
    return all(math.isfinite(v) for v in vals)


class Autopilot:
    """One emulated autopilot (sysid ``sysid``, compid 1) plus the load's own MAVLink system (sysid ``load_sysid``).

    Parameters
    ----------
    flavor: ``"px4"`` or ``"ardupilot"``.
    vehicle: the plant's vehicle (its constants are also exposed as read-only EMU_* parameters).
    link: the link the packets go out on (``Link.write`` is pymavlink's file).
    dt: plant step, s.
    signing_key: 32-byte MAVLink 2 secret key, or None for no signing.
    est_ready_s: simulation time after boot at which the estimator reports a position (arming refused before).
    sensors, sensor_rng: the telemetry's sensor preset (``sim_bridge.sensors.PRESETS``) and its seeded generator
    (``sim_bridge.telemetry``); the inner loops and hold modes use the plant truth.
    """

    def __init__(
        self,
        flavor: str,
        vehicle: Vehicle,
        link: Link,
        *,
        dt: float = 0.001,
        sysid: int = 1,
        load_sysid: int = 2,
        signing_key: bytes | None = None,
        home: Home | None = None,
        noise: float = 0.0,
        rng: Any = None,
        est_ready_s: float = 1.5,
        attitude_model: str = "rigid",
        sensors: str = "ideal",
        sensor_rng: Any = None,
    ) -> None:
        self.fl: Flavor = make_flavor(flavor, vehicle)
        self.vehicle = vehicle
        self.link = link
        self.dt = dt
        self.sysid = sysid
        self.home = home or Home()
        d = _common if self.fl.dialect == "common" else _apm
        self.d = d
        self.mav = d.MAVLink(link, srcSystem=sysid, srcComponent=1)
        self.mav_load = d.MAVLink(link, srcSystem=load_sysid, srcComponent=LOAD_COMPID)
        self.rx_mav = d.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.signing = signing_key is not None
        if signing_key is not None:
            if len(signing_key) != 32:
                raise ValueError("signing key must be 32 bytes")
            ts = int((time.time() - 1420070400) * 1e5)
            for i, m in enumerate((self.mav, self.mav_load, self.rx_mav)):
                m.signing.secret_key = signing_key
                m.signing.sign_outgoing = m is not self.rx_mav
                m.signing.timestamp = ts
                m.signing.link_id = i
                m.signing.allow_unsigned_callback = _allow_unsigned
        self.pp = plant_params(vehicle, attitude_model)
        self.tel = TelemetrySource(self.pp, self.home, noise, rng, sensors=sensors, sensor_rng=sensor_rng,
                                   step_us=round(dt * 1e6))
        self._tel_history = self.tel.needs_history
        self.boot_unix_us = int(time.time() * 1e6)
        self.est_ready_us = int(est_ready_s * 1e6)

        # airframe
        self.mixer = Mixer(vehicle, dt)
        self.att = AttitudeController(vehicle, 2 * dt)  # rate loop at half the plant rate (500 Hz at 1 kHz)
        self.pos = PositionController(vehicle.gravity)
        self.weight = vehicle.total_mass * vehicle.gravity
        self.tmax = vehicle.thrust_max


        # state machine
        self.mode: Mode = self.fl.by_name[self.fl.boot_mode]
        self.armed = False
        self.terminated = False
        self.t_us = 0
        self.x: Sequence[float] = [0.0] * 18
        self.u: list[float] = [0.0] * 13
        self.on_ground = True
        self.has_flown = False
        self.ground_since_us = 0
        self.armed_at_us = 0
        self.k = 0
        # setpoint memory (model frame)
        self.sp_kind = "none"  # att | rates | pos | direct | none
        self.sp_time_us = -10**12
        self.sp_q = (1.0, 0.0, 0.0, 0.0)
        self.sp_rates = (0.0, 0.0, 0.0)
        self.sp_yaw_ff = 0.0
        self.sp_thrust = 0.0  # normalized (PX4) / raw thrust field (ArduPilot)
        self.sp_pos: tuple[float | None, float | None, float | None] = (None, None, None)
        self.sp_vel = (0.0, 0.0, 0.0)
        self.sp_yaw: float | None = None
        self.sp_direct = (0.0, 0.0, 0.0, 0.0)
        self.sp_mask = 0
        self.last_sp_wall = 0.0
        # mode targets (model frame)
        self.hold_pos: tuple[float | None, float | None, float | None] = (0.0, 0.0, 0.0)
        self.hold_yaw = 0.0
        self.z_target = 0.0
        self.rtl_phase = 0
        self.takeoff_alt = 2.5
        self.braking = False
        self.guided_sub = "hold"  # AP GUIDED: hold | att | pos | takeoff | timeout
        self.failsafe = False
        # inner-loop outputs
        self.rate_sp = (0.0, 0.0, 0.0)
        self.q_sp = (1.0, 0.0, 0.0, 0.0)
        self.thrust_cmd = 0.0  # N
        self.direct_tau: tuple[float, float, float] | None = None
        # counters
        self.counters: dict[str, int] = {
            "setpoints_accepted": 0, "setpoints_rejected": 0, "setpoints_ignored": 0, "commands": 0,
            "commands_unsupported": 0, "statustexts": 0, "param_sets": 0, "failsafes": 0, "arms": 0,
            "arm_refusals": 0, "mode_changes": 0, "mode_refusals": 0, "touchdowns": 0, "handler_errors": 0,
        }
        self.mode_log: list[tuple[float, str]] = [(0.0, self.mode.name)]
        #: simulation time (µs) of the first entry into OFFBOARD (PX4) or GUIDED / GUIDED_NOGPS (ArduPilot)
        self.offboard_entry_us: int | None = None
        self._last_err_report_us = 0
        self._last_err_total = 0

        # streams: name -> [interval_us (0 = off), next_due_us]
        self.streams: dict[str, list[int]] = {}
        self.msgid_to_name: dict[int, str] = {}
        for name in BUILDERS:
            cls = getattr(d, "MAVLink_" + name.lower() + "_message")
            self.msgid_to_name[cls.id] = name
            hz = self.fl.rates.get(name, 0.0)
            self.streams[name] = [round(1e6 / hz) if hz > 0 else 0, 0]
        self.load_streams = {"HEARTBEAT": [1_000_000, 0], "GLOBAL_POSITION_INT": [100_000, 0],
                             "ATTITUDE": [100_000, 0]}
        self.next_due = 0
        self.lockstep_marker = False

        # parameters
        self.params = self.fl.params
        self.param_names = list(self.params)
        self._apply_params()

    # ================================================================== parameters
    def _p(self, name: str) -> float:
        return self.params[name].value

    def _apply_params(self, changed: str | None = None) -> None:
        """Push parameter values into the controllers (at start and after every PARAM_SET of ``changed``)."""
        att, pos = self.att, self.pos
        if self.fl.is_px4:
            att.att_p = [self._p("MC_ROLL_P"), self._p("MC_PITCH_P"), self._p("MC_YAW_P")]
            att.rate_p = [self._p("MC_ROLLRATE_P"), self._p("MC_PITCHRATE_P"), self._p("MC_YAWRATE_P")]
            att.rate_i = [self._p("MC_ROLLRATE_I"), self._p("MC_PITCHRATE_I"), self._p("MC_YAWRATE_I")]
            att.rate_max = [math.radians(self._p("MC_ROLLRATE_MAX")), math.radians(self._p("MC_PITCHRATE_MAX")),
                            math.radians(self._p("MC_YAWRATE_MAX"))]
            pos.xy_p, pos.z_p = self._p("MPC_XY_P"), self._p("MPC_Z_P")
            pos.xy_vel_p, pos.xy_vel_i = self._p("MPC_XY_VEL_P_ACC"), self._p("MPC_XY_VEL_I_ACC")
            pos.z_vel_p, pos.z_vel_i = self._p("MPC_Z_VEL_P_ACC"), self._p("MPC_Z_VEL_I_ACC")
            pos.xy_speed_max = self._p("MPC_XY_CRUISE")
            pos.z_speed_up, pos.z_speed_down = self._p("MPC_Z_VEL_MAX_UP"), self._p("MPC_Z_VEL_MAX_DN")
            pos.tilt_max = math.radians(min(self._p("MPC_TILTMAX_AIR"), 60.0))
            self.hover_norm = self._p("MPC_THR_HOVER")
        else:
            att.att_p = [self._p("ATC_ANG_RLL_P"), self._p("ATC_ANG_PIT_P"), self._p("ATC_ANG_YAW_P")]
            att.rate_p = [self._p("ATC_RAT_RLL_P"), self._p("ATC_RAT_PIT_P"), self._p("ATC_RAT_YAW_P")]
            att.rate_i = [self._p("ATC_RAT_RLL_I"), self._p("ATC_RAT_PIT_I"), self._p("ATC_RAT_YAW_I")]
            pos.xy_p, pos.z_p = self._p("PSC_POSXY_P"), self._p("PSC_POSZ_P")
            pos.xy_vel_p, pos.z_vel_p = self._p("PSC_VELXY_P"), self._p("PSC_VELZ_P")
            pos.xy_speed_max = self._p("WPNAV_SPEED") / 100.0
            pos.z_speed_up, pos.z_speed_down = self._p("WPNAV_SPEED_UP") / 100.0, self._p("WPNAV_SPEED_DN") / 100.0
            pos.tilt_max = math.radians(min(self._p("ANGLE_MAX") / 100.0, 60.0))
            self.hover_norm = self._p("MOT_THST_HOVER")
            groups = _ap_groups()
            if changed in groups:
                hz = self._p(changed)
                for n in groups[changed]:
                    self._set_interval(n, int(1e6 / hz) if hz > 0 else 0)

    def _param_wire(self, name: str) -> float:
        """A parameter's value as it travels in PARAM_VALUE.param_value (PX4 ints bytewise, ArduPilot C cast)."""
        p = self.params[name]
        if p.ptype in (INT8, INT16, INT32) and self.fl.is_px4:
            return struct.unpack("<f", struct.pack("<i", int(p.value)))[0]
        return float(p.value)

    def _send_param(self, name: str) -> None:
        p = self.params[name]
        self.mav.send(self.mav.param_value_encode(name.encode(), self._param_wire(name), p.ptype,
                                                  len(self.param_names), self.param_names.index(name)))

    # ================================================================== outgoing helpers
    def statustext(self, severity: int, text: str) -> None:
        """Send a STATUSTEXT (truncated to 50 characters) from the autopilot."""
        self.counters["statustexts"] += 1
        self.mav.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    def heartbeat(self, mav: Any) -> Any:
        """HEARTBEAT message of the autopilot (type QUADROTOR, the flavour's autopilot type and mode encoding)."""
        base = self.mode.base_flags | (SAFETY_ARMED if self.armed else 0)
        if self.failsafe or self.terminated:
            status = 5  # MAV_STATE_CRITICAL
        elif self.armed:
            status = 4  # ACTIVE
        elif self.t_us < self.est_ready_us:
            status = 2  # CALIBRATING (estimator initialising)
        else:
            status = 3  # STANDBY
        return mav.heartbeat_encode(2, self.fl.autopilot_type, base, self.mode.custom_mode, status)

    def sys_status(self, mav: Any) -> Any:
        """SYS_STATUS: sensors all present/healthy; link counters in the error fields (docs/emulator.md)."""
        rx = self.link.rx
        bad = rx.bad_crc + rx.truncated + rx.garbage_datagrams + rx.malformed + rx.unknown_msgid
        sensors = 0x3FFFFF & ~(1 << 16)
        drop = 0 if rx.datagrams == 0 else int(10000 * (bad + rx.dropped_in) / rx.datagrams)
        c = 65535
        return mav.sys_status_encode(sensors, sensors, sensors, 100, 12600, -1, 100, min(drop, 10000), min(bad, c),
                                     min(rx.unsigned_rejected + rx.bad_signature, c), min(rx.foreign_target, c),
                                     min(rx.garbage_datagrams, c), min(self.counters["setpoints_rejected"], c))

    def landed_state(self) -> int:
        """MAV_LANDED_STATE: 1 on ground, 2 in air, 3 taking off, 4 landing."""
        if self.on_ground:
            return 1
        if self.mode.kind == "takeoff":
            return 3
        if self.mode.kind == "land" or (self.mode.kind == "rtl" and self.rtl_phase == 2):
            return 4
        return 2

    def throttle_fraction(self) -> float:
        """Current collective thrust as a fraction of the maximum."""
        return min(max(self.thrust_cmd / self.tmax, 0.0), 1.0)

    def attitude_target_wire(self) -> tuple[tuple[float, ...], tuple[float, float, float], float, int]:
        """(q NED, body rates FRD, normalized thrust, type_mask) of what the inner loop tracks."""
        q = model_quaternion_to_ned(*self.q_sp)
        rates = model_body_to_frd(*self.rate_sp)
        return q, rates, self.throttle_fraction(), 0

    # ================================================================== modes
    def _kind(self) -> str:
        return self.mode.kind

    def _set_mode(self, mode: Mode, reason: str = "") -> None:
        """Enter a mode: capture the hold targets from the current state."""
        x = self.x
        prev = self.mode
        self.mode = mode
        self.counters["mode_changes"] += 1
        self.mode_log.append((self.t_us / 1e6, mode.name))
        self.hold_pos = (x[0], x[1], max(x[2], 0.0))
        self.hold_yaw = x[8]
        self.z_target = max(x[2], 0.0)
        self.braking = not self.on_ground
        self.failsafe = bool(reason)
        if mode.kind == "rtl":
            self.rtl_phase = 0
        if mode.kind == "takeoff" and prev.kind != "takeoff":
            self.takeoff_alt = self._p("MIS_TAKEOFF_ALT") if self.fl.is_px4 else 2.5
        if mode.kind == "guided":
            self.guided_sub = "hold"
        if mode.kind in ("offboard", "guided") and self.offboard_entry_us is None:
            self.offboard_entry_us = self.t_us
        self.pos.reset()
        if reason:
            self.statustext(WARNING, reason)

    def _hold_altitude(self, alt: float) -> None:
        """Hold the current horizontal position at ``alt`` (m above home, model frame z up)."""
        self.hold_pos = (self.hold_pos[0], self.hold_pos[1], alt)
        self.z_target = alt
        self.braking = False  # a setpoint is given: no 'stop first, then hold where stopped'

    def _can_enter(self, mode: Mode) -> tuple[bool, int, str]:
        """Mode-entry rules of the real autopilots: (allowed, MAV_RESULT if not, STATUSTEXT reason)."""
        ready = self.t_us >= self.est_ready_us
        needs_pos = mode.kind in ("hold", "takeoff", "rtl", "offboard", "guided", "land")
        if self.fl.is_px4:
            if mode.kind == "offboard" and not self._offboard_signal_ok():
                return False, TEMPORARILY_REJECTED, "Switching to Offboard is currently not possible"
            if needs_pos and not ready and mode.kind != "offboard":
                return False, TEMPORARILY_REJECTED, f"Switching to {mode.name} is currently not possible"
            return True, ACCEPTED, ""
        if mode.name == "GUIDED_NOGPS" or mode.kind in ("stabilized", "acro", "althold"):
            return True, ACCEPTED, ""
        if needs_pos and not ready:
            return False, FAILED, "Flight mode change failed"
        return True, ACCEPTED, ""

    def request_mode(self, mode: Mode) -> int:
        """Try to switch mode (from a command); returns the MAV_RESULT."""
        if mode is self.mode:
            return ACCEPTED
        ok, res, why = self._can_enter(mode)
        if not ok:
            self.counters["mode_refusals"] += 1
            if why:
                self.statustext(CRITICAL if self.fl.is_px4 else WARNING, why)
            return res
        self._set_mode(mode)
        return ACCEPTED

    def _offboard_signal_ok(self) -> bool:
        """PX4: a setpoint stream younger than COM_OF_LOSS_T (the 'proof of life')."""
        return self.sp_kind != "none" and self.t_us - self.sp_time_us <= self._p("COM_OF_LOSS_T") * 1e6

    # ================================================================== arming
    def _arm(self, force_value: float) -> int:
        if self.armed:
            return ACCEPTED
        px4 = self.fl.is_px4
        skip_checks = (not px4) and round(force_value) == AP_FORCE_ARM
        reason = ""
        if not skip_checks:
            if self.t_us < self.est_ready_us:
                reason = "Preflight Fail: ekf2 missing data" if px4 else "PreArm: Need Position Estimate"
            elif not self.mode.armable:
                reason = (f"Arming denied: not allowed in {self.mode.name}" if px4
                          else "Arm: Mode not armable")
            elif px4 and self.mode.kind == "offboard" and not self._offboard_signal_ok():
                reason = "Arming denied: offboard signal lost"
        if reason:
            self.counters["arm_refusals"] += 1
            self.statustext(CRITICAL, reason)
            return TEMPORARILY_REJECTED if px4 else FAILED
        self.armed = True
        self.terminated = False
        self.has_flown = False
        self.armed_at_us = self.t_us
        self.ground_since_us = self.t_us
        self.counters["arms"] += 1
        self.att.reset()
        self.pos.reset()
        self.hold_pos = (self.x[0], self.x[1], max(self.x[2], 0.0))
        self.z_target = max(self.x[2], 0.0)
        self.statustext(INFO, "Armed by external command" if px4 else "Arming motors")
        return ACCEPTED

    def _disarm(self, force_value: float, reason: str = "") -> int:
        if not self.armed:
            return ACCEPTED
        forced = round(force_value) == PX4_FORCE
        if not self.on_ground and not forced and not reason:
            self.statustext(CRITICAL, "Disarming denied: not landed" if self.fl.is_px4 else "Disarm: not landed")
            return TEMPORARILY_REJECTED if self.fl.is_px4 else FAILED
        self.armed = False
        self.statustext(INFO, reason or ("Disarmed by external command" if self.fl.is_px4 else "Disarming motors"))
        return ACCEPTED

    # ================================================================== incoming
    def handle_datagram(self, data: bytes, ep: Any, addr: tuple[str, int]) -> int:
        """Decode one datagram and act on its messages; returns the number of accepted setpoints."""
        link = self.link
        rx = link.rx
        n = 0
        for frame in link.frames(data):
            try:
                msg = self.rx_mav.decode(bytearray(frame))
            except _common.MAVError as exc:
                text = str(exc)
                if "CRC" in text:
                    rx.bad_crc += 1
                elif "signature" in text:
                    link.log_received(frame)
                    if frame[0] == 0xFD and frame[2] & 0x01:
                        rx.bad_signature += 1
                    else:
                        rx.unsigned_rejected += 1
                else:
                    rx.malformed += 1
                continue
            except Exception:
                rx.malformed += 1
                continue
            if msg.get_type() == "UNKNOWN" or msg.__class__.__name__ == "MAVLink_unknown":
                rx.unknown_msgid += 1
                continue
            link.log_received(frame)
            rx.packets_ok += 1
            ep.add_peer(addr)
            try:
                n += self._dispatch(msg)
            except Exception:  # a message that breaks a handler must not stop the emulator: counted, logged
                self.counters["handler_errors"] += 1
                log.warning("error handling %s", msg.get_type(), exc_info=True)
        return n

    def _dispatch(self, msg: Any) -> int:
        t = msg.get_type()
        ts = getattr(msg, "target_system", None)
        if ts is not None and ts not in (0, self.sysid):
            self.link.rx.foreign_target += 1
            return 0
        tc = getattr(msg, "target_component", None)
        if tc is not None and tc not in (0, 1) and t not in ("PING",):
            self.link.rx.foreign_target += 1
            return 0
        h = _HANDLERS.get(t)
        if h is None:
            return 0
        return h(self, msg) or 0

    # ---------------------------------------------------------------- commands
    def _ack(self, msg: Any, command: int, result: int) -> None:
        self.mav.send(self.mav.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(),
                                                  msg.get_srcComponent()))

    def _on_command(self, msg: Any) -> int:
        self.counters["commands"] += 1
        cmd = msg.command
        p = (msg.param1, msg.param2, msg.param3, msg.param4)
        p7 = msg.z if msg.get_type() == "COMMAND_INT" else msg.param7
        result, after = self._command(cmd, p, p7, msg)
        self._ack(msg, cmd, result)
        if after is not None:
            after()
        return 0

    def _command(self, cmd: int, p: tuple[float, ...], p7: float, msg: Any) -> tuple[int, Any]:
        d = self.d
        if cmd == d.MAV_CMD_COMPONENT_ARM_DISARM:
            v = round(p[0]) if _finite(p[0]) else None
            if v == 1:
                return self._arm(p[1] if _finite(p[1]) else 0.0), None
            if v == 0:
                return self._disarm(p[1] if _finite(p[1]) else 0.0), None
            # neither arm nor disarm: both autopilots answer UNSUPPORTED (PX4 Commander also logs it)
            if self.fl.is_px4:
                self.statustext(CRITICAL, f"Unsupported ARM_DISARM param: {p[0]:.3f}")
            return UNSUPPORTED, None
        if cmd == d.MAV_CMD_DO_SET_MODE:
            return self._cmd_set_mode(p), None
        if cmd == d.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._cmd_message_interval(p[0], p[1]), None
        if cmd == d.MAV_CMD_GET_MESSAGE_INTERVAL:
            name = self.msgid_to_name.get(int(p[0]) if _finite(p[0]) else -1)
            if name is None:
                return DENIED, None
            iv = self.streams[name][0]
            return ACCEPTED, lambda: self.mav.send(self.mav.message_interval_encode(int(p[0]), iv if iv else -1))
        if cmd == d.MAV_CMD_REQUEST_MESSAGE:
            return self._cmd_request_message(p[0])
        if cmd == 520:  # MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
            return ACCEPTED, self._send_autopilot_version
        if cmd == d.MAV_CMD_NAV_TAKEOFF:
            return self._cmd_takeoff(p7), None
        if cmd == d.MAV_CMD_NAV_LAND:
            return self.request_mode(self.fl.by_name["AUTO.LAND" if self.fl.is_px4 else "LAND"]), None
        if cmd == d.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self.request_mode(self.fl.by_name["AUTO.RTL" if self.fl.is_px4 else "RTL"]), None
        self.counters["commands_unsupported"] += 1
        return UNSUPPORTED, None

    def _cmd_set_mode(self, p: Sequence[float]) -> int:
        if not _finite(p[0], p[1], p[2]) or not (int(p[0]) & 1):
            return DENIED
        if self.fl.is_px4:
            main, sub = int(p[1]), int(p[2])
            custom = (main << 16) | ((sub if main == 4 else 0) << 24)
        else:
            custom = int(p[1])
        mode = self.fl.by_custom.get(custom)
        if mode is None:
            self.counters["mode_refusals"] += 1
            return DENIED if self.fl.is_px4 else FAILED
        return self.request_mode(mode)

    def _cmd_message_interval(self, msgid: float, interval: float) -> int:
        if not _finite(msgid, interval):
            return DENIED
        name = self.msgid_to_name.get(int(msgid))
        if name is None:
            return DENIED
        iv = int(interval)
        if iv == 0:
            hz = self.fl.rates.get(name, 0.0)
            iv = round(1e6 / hz) if hz > 0 else 0
        elif iv < 0:
            iv = 0
        else:
            iv = max(iv, 1000)
        self._set_interval(name, iv)
        return ACCEPTED

    def _set_interval(self, name: str, iv: int) -> None:
        s = self.streams[name]
        s[0] = iv
        s[1] = self.t_us + iv if iv else 0
        self._recompute_next_due()

    def _recompute_next_due(self) -> None:
        nd = min((s[1] for s in self.streams.values() if s[0]), default=1 << 62)
        nd = min(nd, min(s[1] for s in self.load_streams.values()))
        self.next_due = nd

    def _cmd_request_message(self, msgid: float) -> tuple[int, Any]:
        if not _finite(msgid):
            return DENIED, None
        mid = int(msgid)
        if mid == self.d.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return ACCEPTED, self._send_autopilot_version
        name = self.msgid_to_name.get(mid)
        if name is None:
            return DENIED, None
        if name in NEEDS_POSITION and self.t_us < self.est_ready_us:
            return TEMPORARILY_REJECTED, None
        return ACCEPTED, lambda: self._send_stream(name, self.mav)

    def _send_autopilot_version(self) -> None:
        self.mav.send(self.mav.autopilot_version_encode(
            self.fl.capabilities, self.fl.version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5157, [0] * 18))

    def _cmd_takeoff(self, p7: float) -> int:
        if not self.armed:
            self.statustext(CRITICAL, "Takeoff denied: disarmed" if self.fl.is_px4 else "Takeoff: not armed")
            return TEMPORARILY_REJECTED if self.fl.is_px4 else FAILED
        if self.fl.is_px4:
            alt = (p7 - self.home.alt) if _finite(p7) else self._p("MIS_TAKEOFF_ALT")
            r = self.request_mode(self.fl.by_name["AUTO.TAKEOFF"])
            if r == ACCEPTED:
                self.takeoff_alt = max(alt, 0.5)
            return r
        if self.mode.kind != "guided" or not _finite(p7) or p7 <= 0.0:
            return FAILED
        self.guided_sub = "takeoff"
        self.takeoff_alt = p7
        self.hold_pos = (self.x[0], self.x[1], p7)
        return ACCEPTED

    # ---------------------------------------------------------------- setpoints
    def _on_set_attitude_target(self, msg: Any) -> int:
        mask = msg.type_mask
        px4 = self.fl.is_px4
        att = not (mask & 128)
        rates = not (mask & 1) and not (mask & 2)
        use_tb = px4 and bool(mask & 32) and att
        has_thrust = use_tb or not (mask & 64)
        if not px4 and (mask & 64 or (not att and (mask & 7)) or (0 < (mask & 7) < 7)):
            # ArduPilot: thrust mandatory; rates all or none (rejected without a NACK)
            self.counters["setpoints_rejected"] += 1
            return 1
        if not (att or rates) or not has_thrust:
            self.counters["setpoints_ignored"] += 1
            return 1
        q = msg.q
        thrust = -msg.thrust_body[2] if use_tb else msg.thrust
        vals = (*q, msg.body_roll_rate, msg.body_pitch_rate, thrust)
        if att:
            nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            if not (_finite(*q) and _finite(thrust)) or nq < 0.5 or (not px4 and abs(nq - 1.0) > 1e-3):
                self.counters["setpoints_rejected"] += 1
                self.link.rx.malformed += 1
                if not px4 and self.mode.kind == "guided":
                    self.guided_sub = "hold"
                    self.hold_pos = (self.x[0], self.x[1], max(self.x[2], 0.0))
                return 1
            qm = ned_quaternion_to_model(q[0] / nq, q[1] / nq, q[2] / nq, q[3] / nq)
            yaw_ff = 0.0
            if not (mask & 4) and math.isfinite(msg.body_yaw_rate):
                yaw_ff = ned_to_model_vector(0.0, 0.0, msg.body_yaw_rate)[2]  # about world down -> about up
            self.sp_kind, self.sp_q, self.sp_yaw_ff = "att", qm, yaw_ff
            if not px4 and not (mask & 7):
                self.sp_rates = frd_to_model_body(msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate)
        else:
            yr = msg.body_yaw_rate if not (mask & 4) else 0.0
            if not _finite(*vals[4:], yr):
                self.counters["setpoints_rejected"] += 1
                self.link.rx.malformed += 1
                return 1
            self.sp_kind = "rates"
            self.sp_rates = frd_to_model_body(msg.body_roll_rate, msg.body_pitch_rate, yr)
        self.sp_thrust = min(max(thrust, -1.0), 1.0)
        self.sp_mask = mask
        self.sp_time_us = self.t_us
        self.counters["setpoints_accepted"] += 1
        if not px4 and self.mode.kind == "guided":
            self.guided_sub = "att"
        return 1

    def _on_set_position_target_local_ned(self, msg: Any) -> int:
        mask = msg.type_mask
        if msg.coordinate_frame != 1:  # only MAV_FRAME_LOCAL_NED
            self.counters["setpoints_rejected"] += 1
            return 1
        use_pos = (mask & 7) != 7
        use_vel = (mask & 56) != 56
        if not (use_pos or use_vel):
            self.counters["setpoints_ignored"] += 1
            return 1
        pos = ned_to_model_vector(msg.x, msg.y, msg.z)
        vel = ned_to_model_vector(msg.vx, msg.vy, msg.vz)
        if (use_pos and not _finite(*pos)) or (use_vel and not _finite(*vel)):
            self.counters["setpoints_rejected"] += 1
            self.link.rx.malformed += 1
            return 1
        self.sp_pos = (pos[0] if not mask & 1 else None, pos[1] if not mask & 2 else None,
                       pos[2] if not mask & 4 else None)
        self.sp_vel = (vel[0] if not mask & 8 else 0.0, vel[1] if not mask & 16 else 0.0,
                       vel[2] if not mask & 32 else 0.0)
        self.sp_yaw = (ned_euler_to_model(0.0, 0.0, msg.yaw)[2] if not (mask & 1024) and math.isfinite(msg.yaw)
                       else None)
        self.sp_kind = "pos"
        self.sp_time_us = self.t_us
        self.counters["setpoints_accepted"] += 1
        if not self.fl.is_px4 and self.mode.kind == "guided":
            self.guided_sub = "pos"
        return 1

    def _on_set_actuator_control_target(self, msg: Any) -> int:
        if not self.fl.is_px4 or msg.group_mlx != 0:
            self.counters["setpoints_ignored"] += 1
            return 1
        c = msg.controls
        if not _finite(c[0], c[1], c[2], c[3]):
            self.counters["setpoints_rejected"] += 1
            self.link.rx.malformed += 1
            return 1
        self.sp_direct = (min(max(c[0], -1.0), 1.0), min(max(c[1], -1.0), 1.0), min(max(c[2], -1.0), 1.0),
                          min(max(c[3], 0.0), 1.0))
        self.sp_kind = "direct"
        self.sp_time_us = self.t_us
        self.counters["setpoints_accepted"] += 1
        return 1

    # ---------------------------------------------------------------- other messages
    def _on_param_request_list(self, msg: Any) -> int:
        for name in self.param_names:
            self._send_param(name)
        return 0

    def _on_param_request_read(self, msg: Any) -> int:
        if msg.param_index >= 0:
            if msg.param_index < len(self.param_names):
                self._send_param(self.param_names[msg.param_index])
            return 0
        name = _param_id(msg.param_id)
        if name in self.params:
            self._send_param(name)
        return 0

    def _on_param_set(self, msg: Any) -> int:
        name = _param_id(msg.param_id)
        p = self.params.get(name)
        if p is None:
            return 0
        if p.ptype in (INT8, INT16, INT32):
            if self.fl.is_px4:
                v: float = struct.unpack("<i", struct.pack("<f", msg.param_value))[0]
            else:
                v = float(round(msg.param_value)) if math.isfinite(msg.param_value) else float("nan")
        else:
            v = msg.param_value
        if p.readonly or not math.isfinite(v) or not (p.lo <= v <= p.hi):
            if not p.readonly:
                self.statustext(WARNING, f"param {name}: {v:g} out of range [{p.lo:g}, {p.hi:g}]")
            self._send_param(name)
            return 0
        p.value = int(v) if p.ptype in (INT8, INT16, INT32) else float(v)
        self.counters["param_sets"] += 1
        self._apply_params(name)
        self._send_param(name)
        return 0

    def _on_set_mode(self, msg: Any) -> int:
        if self.fl.is_px4:
            main, sub = (msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF
            p = (float(msg.base_mode), float(main), float(sub))
            res = self._cmd_set_mode(p)
            cmd = self.d.MAV_CMD_DO_SET_MODE
        else:
            res = self._cmd_set_mode((float(msg.base_mode), float(msg.custom_mode), 0.0))
            cmd = 11
        self._ack(msg, cmd, res)
        return 0

    def _on_ping(self, msg: Any) -> int:
        if msg.target_system == 0:
            self.mav.send(self.mav.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))
        return 0

    def _on_timesync(self, msg: Any) -> int:
        if msg.tc1 == 0:
            self.mav.send(self.mav.timesync_encode(self.t_us * 1000, msg.ts1))
        return 0

    def _on_request_data_stream(self, msg: Any) -> int:
        return 0

    # ================================================================== per-step
    def control(self, x: Sequence[float], on_ground: bool) -> tuple[float, float, float, float]:
        """Inner loops for one plant step: returns the actual (thrust N, tau FLU N m) after mixer and motors."""
        self.x = x
        self.on_ground = on_ground
        mixer = self.mixer
        if not self.armed or self.terminated:
            mixer.cmd = [0.0, 0.0, 0.0, 0.0]
            self.thrust_cmd = 0.0
            return mixer.step()
        k = self.k
        if k & 3 == 0:
            self._outer(x, on_ground)
        if k & 1 == 0:  # rate loop + mixer at 500 Hz (PX4's IMU_GYRO_RATEMAX default is 400 Hz)
            if self.direct_tau is not None:
                tx, ty, tz = self.direct_tau
            else:
                w = body_rates(x[6], x[7], x[9], x[10], x[11])
                tx, ty, tz = self.att.rates_to_torque(self.rate_sp, w, not on_ground)
            mixer.allocate(self.thrust_cmd, tx, ty, tz)
        return mixer.step()

    def _q_now(self, x: Sequence[float]) -> tuple[float, float, float, float]:
        return euler_to_quaternion(x[6], x[7], x[8])

    def _level_q(self, yaw: float) -> tuple[float, float, float, float]:
        return euler_to_quaternion(0.0, 0.0, yaw)

    def _outer(self, x: Sequence[float], on_ground: bool) -> None:
        """Mode logic at 250 Hz: sets ``rate_sp`` and ``thrust_cmd`` (or ``direct_tau``)."""
        dt = 4 * self.dt
        self.direct_tau = None
        kind = self.mode.kind
        px4 = self.fl.is_px4
        if kind == "offboard":
            if not self._offboard_signal_ok():
                self._offboard_lost()
                kind = self.mode.kind
            else:
                sk = self.sp_kind
                if sk == "att":
                    self._track_attitude(x, self.sp_q, px4_thrust_newtons(self.sp_thrust, self.tmax), self.sp_yaw_ff)
                    return
                if sk == "rates":
                    self.q_sp = self._q_now(x)
                    self.rate_sp = self.sp_rates
                    self.thrust_cmd = px4_thrust_newtons(self.sp_thrust, self.tmax)
                    return
                if sk == "direct":
                    c = self.sp_direct
                    t_frd = (c[0] * self.att.tmax[0], c[1] * self.att.tmax[1], c[2] * self.att.tmax[2])
                    self.direct_tau = frd_to_model_body(*t_frd)
                    self.thrust_cmd = c[3] * self.tmax
                    self.q_sp = self._q_now(x)
                    return
                if sk == "pos":
                    yaw = self.sp_yaw if self.sp_yaw is not None else self.hold_yaw
                    self._position(x, self.sp_pos, self.sp_vel, yaw, dt, on_ground)
                    return
        if kind == "guided":
            self._guided(x, dt, on_ground)
            return
        if kind == "hold":
            if self.braking:  # like PX4 Hold / ArduPilot BRAKE: stop first, then hold where stopped
                if x[3] * x[3] + x[4] * x[4] + x[5] * x[5] < 0.09:
                    self.braking = False
                    self.hold_pos = (x[0], x[1], max(x[2], 0.0))
                else:
                    self._position(x, (None, None, None), (0.0, 0.0, 0.0), self.hold_yaw, dt, on_ground)
                    return
            self._position(x, self.hold_pos, (0.0, 0.0, 0.0), self.hold_yaw, dt, on_ground)
        elif kind == "althold":
            self._althold(x, self.z_target, 0.0, self.hold_yaw, dt, on_ground)
        elif kind in ("stabilized", "acro"):
            if kind == "acro":
                self.q_sp = self._q_now(x)
                self.rate_sp = (0.0, 0.0, 0.0)
                self.thrust_cmd = self.hover_norm * self.tmax
            else:
                self._track_attitude(x, self._level_q(self.hold_yaw), self.hover_norm * self.tmax, 0.0)
        elif kind == "takeoff":
            alt = self.takeoff_alt
            up = self._p("MPC_TKO_SPEED") if px4 else None
            self._position(x, (self.hold_pos[0], self.hold_pos[1], alt), (0.0, 0.0, 0.0), self.hold_yaw, dt,
                           False, z_up=up)
            if x[2] >= alt - 0.1:
                self._set_mode(self.fl.by_name["AUTO.LOITER"])
                # PX4's navigator ends the take-off with a loiter setpoint AT the take-off altitude, which
                # Hold keeps: not where the vehicle was when it came within the acceptance band
                self._hold_altitude(alt)
        elif kind == "land":
            self._land(x, dt, on_ground)
        elif kind == "rtl":
            self._rtl(x, dt, on_ground)

    def _land_speed(self) -> float:
        return self._p("MPC_LAND_SPEED") if self.fl.is_px4 else self._p("LAND_SPEED") / 100.0

    def _land(self, x: Sequence[float], dt: float, on_ground: bool) -> None:
        if on_ground:
            self._idle(x)
            return
        sp = self._land_speed()
        self._position(x, (self.hold_pos[0], self.hold_pos[1], None), (0.0, 0.0, -sp), self.hold_yaw, dt, False)

    def _rtl(self, x: Sequence[float], dt: float, on_ground: bool) -> None:
        alt = self._p("RTL_RETURN_ALT") if self.fl.is_px4 else self._p("RTL_ALT") / 100.0
        if self.rtl_phase == 0:
            target_alt = max(alt, self.hold_pos[2] or 0.0)
            self.hold_pos = (self.hold_pos[0], self.hold_pos[1], target_alt)
            self._position(x, self.hold_pos, (0.0, 0.0, 0.0), self.hold_yaw, dt, False)
            if x[2] >= target_alt - 0.3:
                self.rtl_phase = 1
        elif self.rtl_phase == 1:
            z = self.hold_pos[2]
            self._position(x, (0.0, 0.0, z), (0.0, 0.0, 0.0), self.hold_yaw, dt, False)
            if math.hypot(x[0], x[1]) < 0.5:
                self.rtl_phase = 2
                self.hold_pos = (0.0, 0.0, z)
        else:
            self._land(x, dt, on_ground)

    def _idle(self, x: Sequence[float]) -> None:
        """On the ground with nowhere to go: motors at zero thrust, integrators cleared."""
        self.thrust_cmd = 0.0
        self.q_sp = self._q_now(x)
        self.rate_sp = (0.0, 0.0, 0.0)
        self.att.reset()
        self.pos.reset()

    def _track_attitude(self, x: Sequence[float], qd: tuple[float, ...], thrust_n: float, yaw_ff: float) -> None:
        self.q_sp = qd  # type: ignore[assignment]
        self.rate_sp = self.att.attitude_to_rates(self._q_now(x), qd, yaw_ff)
        self.thrust_cmd = min(max(thrust_n, 0.0), self.tmax)

    def _position(self, x: Sequence[float], pos_sp: tuple[float | None, ...], vel_ff: tuple[float, float, float],
                  yaw: float, dt: float, on_ground: bool, z_up: float | None = None) -> None:
        if on_ground and (pos_sp[2] is None or pos_sp[2] < 0.1) and vel_ff[2] <= 0.0:
            self._idle(x)
            return
        q, thr = self.pos.update((x[0], x[1], x[2]), (x[3], x[4], x[5]), pos_sp, vel_ff, yaw,  # type: ignore[arg-type]
                                 self.hover_norm, dt, z_speed_up=z_up)
        self._track_attitude(x, q, thr * self.tmax, 0.0)

    def _vertical_thrust(self, x: Sequence[float], z_sp: float, vz_ff: float, dt: float) -> float:
        """Altitude controller (P on height, PI on climb rate) -> normalized thrust before angle boost."""
        pc = self.pos
        vz = vz_ff + pc.z_p * (z_sp - x[2])
        vz = min(max(vz, -pc.z_speed_down), pc.z_speed_up)
        e = vz - x[5]
        if abs(e) < 0.5:  # integrate near the setpoint only (no wind-up while braking or climbing)
            pc.int_z = min(max(pc.int_z + pc.z_vel_i * e * dt, -4.0), 4.0)
        a = pc.z_vel_p * e + pc.int_z
        g = self.vehicle.gravity
        return (g + max(a, -0.8 * g)) / g * self.hover_norm

    def _althold(self, x: Sequence[float], z_sp: float, vz_ff: float, yaw: float, dt: float, on_ground: bool) -> None:
        if on_ground and z_sp < 0.1 and vz_ff <= 0.0:
            self._idle(x)
            return
        thr = angle_boost(self._vertical_thrust(x, z_sp, vz_ff, dt), x[6], x[7])
        self._track_attitude(x, self._level_q(yaw), min(thr, 1.0) * self.tmax, 0.0)

    def _guided(self, x: Sequence[float], dt: float, on_ground: bool) -> None:
        """ArduPilot GUIDED / GUIDED_NOGPS."""
        sub = self.guided_sub
        if sub in ("att", "pos") and self.sp_kind in ("att", "rates", "pos"):
            timeout = self._p("GUID_TIMEOUT") * 1e6
            if sub == "att" and self.t_us - self.sp_time_us > timeout:
                self.guided_sub = sub = "timeout"
                self.z_target = x[2]
                self.hold_yaw = x[8]
                self.statustext(WARNING, "Guided: attitude target timed out")
        if sub == "att":
            thrust = self.sp_thrust
            use_thrust = int(self._p("GUID_OPTIONS")) & 8
            rate_only = bool(self.sp_mask & 128)
            if use_thrust:
                thrust_n = ardupilot_throttle_newtons(thrust, x[6], x[7], bool(int(self._p("ATC_ANGLE_BOOST"))),
                                                      self.tmax)
            else:
                climb = ardupilot_climb_rate(thrust, self._p("WPNAV_SPEED_UP") / 100.0,
                                             self._p("WPNAV_SPEED_DN") / 100.0)
                if on_ground and climb <= 0.0:
                    self._idle(x)
                    self.z_target = 0.0
                    return
                self.z_target = min(max(self.z_target + climb * dt, x[2] - 2.0), x[2] + 2.0)
                thr = angle_boost(self._vertical_thrust(x, self.z_target, climb, dt), x[6], x[7])
                thrust_n = min(thr, 1.0) * self.tmax
            if rate_only:
                self.q_sp = self._q_now(x)
                self.rate_sp = self.sp_rates
                self.thrust_cmd = thrust_n
            else:
                self._track_attitude(x, self.sp_q, thrust_n, self.sp_yaw_ff)
            return
        if sub == "timeout":  # level, zero climb rate: stop the vertical motion, then hold that height
            if abs(x[5]) > 0.2:
                self.z_target = x[2]
            self._althold(x, self.z_target, 0.0, self.hold_yaw, dt, on_ground)
            return
        if sub == "pos":
            yaw = self.sp_yaw if self.sp_yaw is not None else self.hold_yaw
            self._position(x, self.sp_pos, self.sp_vel, yaw, dt, on_ground)
            return
        if sub == "takeoff":
            self._position(x, self.hold_pos, (0.0, 0.0, 0.0), self.hold_yaw, dt, False)
            if x[2] >= self.takeoff_alt - 0.1:
                self.guided_sub = "hold"  # ArduPilot's GUIDED keeps the take-off's target altitude
                self._hold_altitude(self.takeoff_alt)
            return
        self._position(x, self.hold_pos, (0.0, 0.0, 0.0), self.hold_yaw, dt, on_ground)

    def _offboard_lost(self) -> None:
        """PX4 offboard-loss failsafe: COM_OBL_RC_ACT."""
        self.counters["failsafes"] += 1
        act = int(self._p("COM_OBL_RC_ACT"))
        if act == 6:
            self.terminated = True
            self.statustext(EMERGENCY, "Failsafe: offboard signal lost, terminating")
            return
        if act == 7:
            self._disarm(PX4_FORCE, "Failsafe: offboard signal lost, disarming")
            return
        name = PX4_OBL_ACTIONS.get(act, "POSCTL")
        mode = self.fl.by_name[name]
        self._set_mode(mode, f"Failsafe activated: offboard signal lost, {name}")

    def after_step(self, t_us: int, x: Sequence[float], u: Sequence[float], on_ground: bool) -> None:
        """Telemetry that came due, timers and auto-disarm; called after every plant step."""
        self.t_us = t_us
        self.k += 1
        self.x = x
        self.u = u  # type: ignore[assignment]
        if on_ground != self.on_ground:
            if on_ground:
                self.counters["touchdowns"] += 1
            self.ground_since_us = t_us
        self.on_ground = on_ground
        if not on_ground and self.armed:
            self.has_flown = True
        if self.armed and on_ground and (self.k & 63) == 0:
            self._auto_disarm(t_us)
        if self._tel_history:
            self.tel.record(t_us, x, u, on_ground)
        if t_us >= self.next_due:
            self._emit_due(t_us, x, u)

    def _auto_disarm(self, t_us: int) -> None:
        if self.thrust_cmd > self.weight:
            self.ground_since_us = t_us
            return
        if self.fl.is_px4:
            limit = self._p("COM_DISARM_LAND") if self.has_flown else self._p("COM_DISARM_PRFLT")
            why = "Disarmed by landing" if self.has_flown else "Disarmed by auto preflight disarming"
        else:
            limit = float(self._p("DISARM_DELAY")) if self._p("DISARM_DELAY") > 0 else -1.0
            why = "Disarming motors"
        since = t_us - max(self.ground_since_us, self.armed_at_us)
        if limit > 0 and since > limit * 1e6:
            self._disarm(PX4_FORCE, why)

    def _emit_due(self, t_us: int, x: Sequence[float], u: Sequence[float]) -> None:
        snap = None
        nd = 1 << 62
        ready = t_us >= self.est_ready_us
        for name, s in self.streams.items():
            iv = s[0]
            if not iv:
                continue
            if s[1] <= t_us:
                s[1] += iv
                if s[1] <= t_us:
                    s[1] = t_us + iv
                if (name in NEEDS_POSITION and not ready) or (name == "SYSTEM_TIME" and self.lockstep_marker):
                    pass
                else:
                    if snap is None:
                        snap = self.tel.snapshot(t_us, x, u, self.on_ground)
                    self.mav.send(BUILDERS[name](self.mav, snap, self))
            if s[1] < nd:
                nd = s[1]
        for name, s in self.load_streams.items():
            if s[1] <= t_us:
                s[1] += s[0]
                if s[1] <= t_us:
                    s[1] = t_us + s[0]
                ml = self.mav_load
                if name == "HEARTBEAT":
                    ml.send(ml.heartbeat_encode(7, 8, 0, 0, 4))  # AIRSHIP, AUTOPILOT_INVALID, ACTIVE
                elif ready:
                    if snap is None:
                        snap = self.tel.snapshot(t_us, x, u, self.on_ground)
                    fn = msg_load_global_position_int if name == "GLOBAL_POSITION_INT" else msg_load_attitude
                    ml.send(fn(ml, snap, self))
            if s[1] < nd:
                nd = s[1]
        self.next_due = nd
        self._report_errors(t_us)

    def _send_stream(self, name: str, mav: Any) -> None:
        snap = self.tel.snapshot(self.t_us, self.x, self.u, self.on_ground)
        mav.send(BUILDERS[name](mav, snap, self))

    def rephase(self) -> None:
        """Lockstep streaming (re)starts: restart every stream's period and the inner-loop decimation at the
        current step boundary, so what a controller sees does not depend on how long the emulator free-ran."""
        t = self.t_us
        for s in self.streams.values():
            if s[0]:
                s[1] = t + s[0]
        for s in self.load_streams.values():
            s[1] = t + s[0]
        self.k = 0
        self.tel.rephase()
        self._recompute_next_due()

    def send_step_marker(self) -> None:
        """Lockstep: SYSTEM_TIME at the end of every step (its time_boot_ms is the new simulation time)."""
        self.mav.send(self.mav.system_time_encode(self.boot_unix_us + self.t_us, self.t_us // 1000))

    def _report_errors(self, t_us: int) -> None:
        """At most every 5 s: a STATUSTEXT when the link saw new bad / refused packets."""
        if t_us - self._last_err_report_us < 5_000_000:
            return
        rx = self.link.rx
        bad = rx.bad_crc + rx.truncated + rx.garbage_datagrams + rx.malformed + rx.unknown_msgid
        sig = rx.unsigned_rejected + rx.bad_signature
        total = bad + sig + rx.foreign_target
        if total != self._last_err_total:
            self._last_err_total = total
            self._last_err_report_us = t_us
            self.statustext(WARNING, f"link: {bad} bad, {sig} sig rejects, {rx.foreign_target} foreign")

    def summary(self) -> dict[str, Any]:
        """Counters and state for the final report."""
        return {
            "flavor": self.fl.name,
            "sim_time_s": self.t_us / 1e6,
            "mode": self.mode.name,
            "armed": self.armed,
            "position_nwu_m": [self.x[0], self.x[1], self.x[2]],
            "counters": dict(self.counters),
            "signing": self.signing,
            "modes": [[round(t, 3), m] for t, m in self.mode_log],
            "sensors": self.tel.sensors,
            "accel_bias_flu": list(self.tel.accel_bias),
            "offboard_entry_s": None if self.offboard_entry_us is None else self.offboard_entry_us / 1e6,
        }


def _param_id(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]


def _allow_unsigned(mav: Any, msg_id: int) -> bool:
    """Unsigned messages accepted while signing is on: only RADIO_STATUS (from radios), as ArduPilot does."""
    return msg_id == 109


def _ap_groups() -> dict[str, list[str]]:
    from sim_bridge.flavors import AP_GROUPS

    return AP_GROUPS


_HANDLERS = {
    "COMMAND_LONG": Autopilot._on_command,
    "COMMAND_INT": Autopilot._on_command,
    "SET_ATTITUDE_TARGET": Autopilot._on_set_attitude_target,
    "SET_POSITION_TARGET_LOCAL_NED": Autopilot._on_set_position_target_local_ned,
    "SET_ACTUATOR_CONTROL_TARGET": Autopilot._on_set_actuator_control_target,
    "PARAM_REQUEST_LIST": Autopilot._on_param_request_list,
    "PARAM_REQUEST_READ": Autopilot._on_param_request_read,
    "PARAM_SET": Autopilot._on_param_set,
    "SET_MODE": Autopilot._on_set_mode,
    "PING": Autopilot._on_ping,
    "TIMESYNC": Autopilot._on_timesync,
}

__all__ = ["SETPOINT_IDS", "SETPOINT_MSGS", "Autopilot"]
