"""The emulated autopilot's MAVLink behaviour (PX4 or ArduPilot Copter flavour).

Heartbeat, modes and their encodings, arming rules with reasons, commands with COMMAND_ACK, the parameter
protocol, telemetry streams with SET_MESSAGE_INTERVAL, offboard / guided setpoints and their failsafes,
STATUSTEXT, signing checks and the link counters. One autopilot, one file per role:

- this module: the state, the receive side (framing, signing, dispatch), commands, parameters, the summary;
- ``autopilot_setpoints.py``: SET_ATTITUDE_TARGET / SET_POSITION_TARGET_LOCAL_NED / SET_ACTUATOR_CONTROL_TARGET;
- ``autopilot_modes.py``: modes, arming, failsafes, take-off, and what each mode asks of the inner loops;
- ``autopilot_inner.py``: the inner loops per plant step (PX4: ``sim_bridge/inner/px4_inner.py``; ArduPilot:
  ``sim_bridge/inner/airframe.py``), parameters pushed into them, the estimate the modes fly on;
- ``autopilot_params.py``: the parameter protocol and ``set_param``;
- ``autopilot_streams.py``: HEARTBEAT / SYS_STATUS, the stream scheduler, per-step timers, lockstep markers;
- ``autopilot_constants.py``: MAVLink result / severity codes and helpers they share.

The physics lives in ``sim_bridge/plant/dynamics.py``; the clock in ``sim_bridge/emulator.py`` calls

- :meth:`Autopilot.handle_datagram` for each received datagram (returns how many setpoints it accepted, which
  the lockstep clock turns into steps),
- :meth:`Autopilot.control` once per plant step (returns the motors' thrust and torques),
- :meth:`Autopilot.after_step` once per plant step (telemetry that came due, timers, failsafes).

Frames: setpoints arrive in NED / FRD and are converted to the model frame (NWU / FLU) with
``estimators.model.frames`` only; everything inside is model frame, SI.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Sequence
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as _apm
from pymavlink.dialects.v20 import common as _common

from estimators.mavlink_signing import install_checked_signing
from estimators.model.vehicle import Vehicle
from sim_bridge.autopilot_constants import (
    ACCEPTED,
    CRITICAL,
    DENIED,
    FAILED,
    LOAD_COMPID,
    SETPOINT_IDS,
    SETPOINT_MSGS,
    UNSUPPORTED,
    all_finite,
)
from sim_bridge.inner.airframe import (
    AttitudeController,
    Mixer,
    PositionController,
)
from sim_bridge.inner.ardupilot_inner import AttitudeShaper, HoverLearner
from sim_bridge.inner.autopilot_inner import InnerControl
from sim_bridge.inner.px4_hover_thrust import HoverThrustEstimator
from sim_bridge.inner.px4_inner import (
    Px4Allocator,
    Px4AttitudeControl,
    Px4Motors,
    Px4RateControl,
    quad_rotors,
)
from sim_bridge.modes.autopilot_modes import ModeLogic
from sim_bridge.modes.flavors import Flavor, Mode, make_flavor
from sim_bridge.plant.dynamics import plant_params
from sim_bridge.plant.ekf_error import EkfError
from sim_bridge.protocol.autopilot_params import ParameterProtocol
from sim_bridge.protocol.autopilot_setpoints import SetpointHandlers
from sim_bridge.protocol.autopilot_streams import TelemetryStreams
from sim_bridge.protocol.link import Link
from sim_bridge.protocol.messages import BUILDERS
from sim_bridge.protocol.telemetry import Home, TelemetrySource

log = logging.getLogger(__name__)


class Autopilot(ModeLogic, InnerControl, TelemetryStreams, SetpointHandlers, ParameterProtocol):
    """One emulated autopilot (sysid ``sysid``, compid 1) plus the load's own MAVLink system (sysid ``load_sysid``).

    Parameters
    ----------
    flavor: ``"px4"`` or ``"ardupilot"``.
    vehicle: the plant's vehicle (its constants are also exposed as read-only EMU_* parameters).
    link: the link the packets go out on (``Link.write`` is pymavlink's file).
    dt: plant step, s.
    signing_key: 32-byte MAVLink 2 secret key, or None for no signing.
    est_ready_s: simulation time after boot at which the estimator reports a position (arming refused before).
    sensors, sensor_rng: the telemetry's sensor preset (``sim_bridge.plant.sensors.PRESETS``) and its seeded generator
    (``sim_bridge.protocol.telemetry``); the inner loops and hold modes use the plant truth.
    ekf: the position / velocity estimate's error (``sim_bridge.plant.ekf_error``): with it, the modes, holds and
    position setpoints act on the estimate, as a real autopilot's do, and the telemetry reports it.
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
        ekf: EkfError | None = None,
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
            install_checked_signing(self.rx_mav)  # verify before pymavlink stores the timestamp (forged-ts DoS)
        self.pp = plant_params(vehicle, attitude_model)
        self.tel = TelemetrySource(
            self.pp, self.home, noise, rng, sensors=sensors, sensor_rng=sensor_rng, step_us=round(dt * 1e6)
        )
        self._tel_history = self.tel.needs_history
        #: the estimate's error model (None: the autopilot knows the true position); telemetry reports it too
        self.ekf = ekf
        self.tel.ekf = ekf
        self.x_true: Sequence[float] = [0.0] * 18
        self.boot_unix_us = int(time.time() * 1e6)
        self.est_ready_us = int(est_ready_s * 1e6)

        # airframe
        self.mixer = Mixer(vehicle, dt)
        # PX4's own inner-loop structure (sim_bridge.inner.px4_inner); the ArduPilot flavour keeps airframe's cascade
        self.px4_att = Px4AttitudeControl()
        self.px4_rate = Px4RateControl(1.0 / (2 * dt))
        self.px4_alloc = Px4Allocator(quad_rotors(vehicle.frame))
        self.px4_motors = Px4Motors(vehicle, quad_rotors(vehicle.frame), dt)
        # ArduPilot's input-shaped attitude target and hover-throttle learning (sim_bridge.inner.ardupilot_inner)
        self.ap_shaper = AttitudeShaper()
        self.ap_hover = HoverLearner(self.fl.params["MOT_THST_HOVER"].value if not self.fl.is_px4 else 0.5)
        # PX4's hover thrust estimator (sim_bridge.inner.px4_hover_thrust); the ArduPilot flavour leaves it unused
        self.px4_hover = HoverThrustEstimator(
            vehicle.gravity, self.fl.params["MPC_THR_HOVER"].value if self.fl.is_px4 else 0.5
        )
        self.hte_vz_prev: float | None = None  # the estimate's climb rate at the last learning step, m/s
        self.pos_control_ran = False  # the position or altitude controller ran since the last learning step
        #: ArduPilot: the RC throttle stick 0..1 (RC_CHANNELS_OVERRIDE channel 3; SITL's default input is low)
        self.rc_throttle = 0.0
        self.torque_norm_sp = (0.0, 0.0, 0.0)  # PX4: the rate loop's output, FRD, the allocator's unit torques
        self.motor_cmd = [0.0, 0.0, 0.0, 0.0]  # PX4: allocator output 0..1
        self.gyro_noise = (0.0, 0.0, 0.0)  # PX4 with an estimate model: the gyro noise now, rad/s FRD
        self.att = AttitudeController(vehicle, 2 * dt)  # rate loop at half the plant rate (500 Hz at 1 kHz)
        self.pos = PositionController(vehicle.gravity)
        self.weight = vehicle.total_mass * vehicle.gravity
        self.tmax = vehicle.thrust_max

        # state machine
        self.mode: Mode = self.fl.by_name[self.fl.boot_mode]
        #: emulated failing checks (``--refuse``: arm, takeoff, offboard; ``sim_bridge.modes.autopilot_modes``)
        self.refuse: frozenset[str] = frozenset()
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
        self.sp_time_us = -(10**12)
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
            "setpoints_accepted": 0,
            "setpoints_rejected": 0,
            "setpoints_ignored": 0,
            "commands": 0,
            "commands_unsupported": 0,
            "statustexts": 0,
            "param_sets": 0,
            "failsafes": 0,
            "arms": 0,
            "arm_refusals": 0,
            "mode_changes": 0,
            "mode_refusals": 0,
            "touchdowns": 0,
            "handler_errors": 0,
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
        self.load_streams = {"HEARTBEAT": [1_000_000, 0], "GLOBAL_POSITION_INT": [100_000, 0], "ATTITUDE": [100_000, 0]}
        self.next_due = 0
        self.lockstep_marker = False

        # parameters
        self.params = self.fl.params
        self.param_names = list(self.params)
        self._apply_params()

    # ================================================================== parameters
    def _p(self, name: str) -> float:
        return self.params[name].value

    # ================================================================== outgoing helpers
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
        self.mav.send(self.mav.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))

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
            v = round(p[0]) if all_finite(p[0]) else None
            if v == 1:
                return self._arm(p[1] if all_finite(p[1]) else 0.0), None
            if v == 0:
                return self._disarm(p[1] if all_finite(p[1]) else 0.0), None
            # neither arm nor disarm: both autopilots answer UNSUPPORTED (PX4 Commander also logs it)
            if self.fl.is_px4:
                self.statustext(CRITICAL, f"Unsupported ARM_DISARM param: {p[0]:.3f}")
            return UNSUPPORTED, None
        if cmd == d.MAV_CMD_DO_SET_MODE:
            return self._cmd_set_mode(p), None
        if cmd == d.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._cmd_message_interval(p[0], p[1]), None
        if cmd == d.MAV_CMD_GET_MESSAGE_INTERVAL:
            name = self.msgid_to_name.get(int(p[0]) if all_finite(p[0]) else -1)
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
        if not all_finite(p[0], p[1], p[2]) or not (int(p[0]) & 1):
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

    def summary(self) -> dict[str, Any]:
        """Counters and state for the final report."""
        return {
            "flavor": self.fl.name,
            "sim_time_s": self.t_us / 1e6,
            "mode": self.mode.name,
            "armed": self.armed,
            "position_nwu_m": [self.x_true[0], self.x_true[1], self.x_true[2]],
            "counters": dict(self.counters),
            "signing": self.signing,
            "modes": [[round(t, 3), m] for t, m in self.mode_log],
            "sensors": self.tel.sensors,
            "accel_bias_flu": list(self.tel.accel_bias),
            "offboard_entry_s": None if self.offboard_entry_us is None else self.offboard_entry_us / 1e6,
            # the estimate's error model: where the ground sits in the local frame (NED z, m), None without one
            "ekf_ground_local_z_m": None if self.ekf is None else self.ekf.ground_local_z_m,
        }


def _allow_unsigned(mav: Any, msg_id: int) -> bool:
    """Unsigned messages accepted while signing is on: only RADIO_STATUS (from radios), as ArduPilot does."""
    return msg_id == 109


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
    "RC_CHANNELS_OVERRIDE": Autopilot._on_rc_channels_override,
}

__all__ = ["SETPOINT_IDS", "SETPOINT_MSGS", "Autopilot"]
