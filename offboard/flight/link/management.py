"""Vehicle management over MAVLink: pre-flight checks, arming, take-off, the switch to offboard control, and
the end of the flight (hold or land, then disarm).

Mode encodings (``shared/docs/mavlink-facts.md``): MAV_CMD_DO_SET_MODE (176) with param1 = 1
(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED) and

- PX4: param2 = custom main mode, param3 = sub mode: OFFBOARD (6, 0), hold AUTO.LOITER (4, 3), AUTO.LAND (4, 6);
- ArduPilot Copter: param2 = mode number: GUIDED 4, BRAKE 17 (hold), LAND 9. The hold is BRAKE, not LOITER:
  LOITER follows the RC throttle stick, and with the stick low (or no RC) it descends and lands, on the load;
  BRAKE stops and holds position and height by itself, whatever the sticks say.

Take-off: PX4 arms in its hold mode and flies AUTO.TAKEOFF (MAV_CMD_NAV_TAKEOFF, param7 = AMSL altitude);
ArduPilot switches to GUIDED, arms and takes off with MAV_CMD_NAV_TAKEOFF (param7 = altitude above home).
PX4 needs the setpoint stream flowing before DO_SET_MODE(OFFBOARD) (``COM_OF_LOSS_T``): the loop primes it for
``LoopConfig.prime_s`` (>= 1 s) first (``FlightLoop._prime``); the end of the flight (hold / land while streaming
hover setpoints) is the loop's too (``FlightLoop._finish``). ArduPilot in GUIDED takes SET_ATTITUDE_TARGET
directly, but its thrust is a climb rate unless GUID_OPTIONS bit 3 (8) is set:
:meth:`Manager.ensure_ardupilot_thrust_mode` sets and verifies it.

Every function is synchronous and keeps the link alive while it waits through the ``idle`` callback (which
the loop uses to stream setpoints and to read telemetry).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from estimators.errors import UserError
from estimators.model.vehicle import Vehicle
from offboard.flight.link.autopilot_model import AutopilotModel, autopilot_model_from_params
from offboard.flight.link.connection import MavConnection
from offboard.flight.link.telemetry import MESSAGE_IDS

log = logging.getLogger(__name__)

MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_IN_PROGRESS = 5

#: (param2, param3) of DO_SET_MODE per flavour and role
MODES: dict[str, dict[str, tuple[int, int]]] = {
    "px4": {"offboard": (6, 0), "hold": (4, 3), "land": (4, 6), "takeoff": (4, 2)},
    "ardupilot": {"offboard": (4, 0), "hold": (17, 0), "land": (9, 0), "takeoff": (4, 0)},
}


def custom_mode(flavour: str, role: str) -> int:
    """HEARTBEAT.custom_mode of a role's mode (PX4: main << 16 | sub << 24; ArduPilot: the number)."""
    main, sub = MODES[flavour][role]
    return (main << 16) | (sub << 24) if flavour == "px4" else main


Idle = Callable[[], None]

#: streams asked for that an autopilot may rightly refuse, and what then still works: ArduPilot has no DEBUG_VECT
#: stream of its own and refused the request on every flight (issue 38), while a cable-angle sensor's DEBUG_VECT is
#: routed to the companion whatever the autopilot's streams
OPTIONAL_STREAMS = {
    "DEBUG_VECT": "a cable-angle sensor's own DEBUG_VECT is still read when it arrives; without one the filter "
    "estimates the swing from the IMU",
}


#: a take-off command left unacknowledged is sent again (at most this many times) when the vehicle has not climbed
#: above TAKEOFF_CLIMB_M (m above home) within TAKEOFF_CLIMB_WAIT_S (s)
TAKEOFF_RESENDS = 4
TAKEOFF_CLIMB_M = 0.2
TAKEOFF_CLIMB_WAIT_S = 5.0


@dataclass
class ManagementEvent:
    """Something management did or saw: local monotonic time (s), kind, one-line detail."""

    t: float
    kind: str
    detail: str


@dataclass
class Manager:
    """Vehicle management for one connection; ``events`` records every step with its reason."""

    conn: MavConnection
    events: list[ManagementEvent] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    #: the MAV_RESULT of the last :meth:`set_mode` (None: never acknowledged)
    last_mode_result: int | None = None
    #: this manager's arm command was accepted (the heartbeat says so up to a second later)
    armed_here: bool = False

    def note(self, kind: str, detail: str) -> None:
        """Record (and log) an event."""
        self.events.append(ManagementEvent(time.monotonic(), kind, detail))
        log.info("%s: %s", kind, detail)

    @property
    def flavour(self) -> str:
        """``px4`` or ``ardupilot``."""
        assert self.conn.vehicle is not None
        return self.conn.vehicle.flavour

    # ---------------------------------------------------------------------------------- configuration ---
    def request_streams(self, rates_hz: dict[str, float], idle: Idle | None = None) -> dict[str, int | None]:
        """SET_MESSAGE_INTERVAL for each message name -> rate (Hz); returns the MAV_RESULT of each. A refusal is a
        warning, except for the streams in :data:`OPTIONAL_STREAMS`, whose refusal is only noted."""
        out: dict[str, int | None] = {}
        for name, hz in rates_hz.items():
            out[name] = self.conn.set_message_interval(MESSAGE_IDS[name], hz, idle=idle)
            if out[name] == MAV_RESULT_ACCEPTED:
                continue
            if name in OPTIONAL_STREAMS:
                self.note(
                    "streams", f"{name} not streamed by the autopilot (result {out[name]}): {OPTIONAL_STREAMS[name]}"
                )
            else:
                self.warnings.append(f"autopilot did not accept {name} at {hz:g} Hz (result {out[name]})")
        self.note("streams", ", ".join(f"{k} {v:g} Hz" for k, v in rates_hz.items()))
        return out

    def read_autopilot_model(self, vehicle: Vehicle, angle_boost_default: bool = True) -> AutopilotModel:
        """The autopilot's attitude / rate gains and hover throttle, read as parameters, as an
        :class:`AutopilotModel` (``autopilot_model.autopilot_model_from_params``); defaults (with a warning) for
        parameters that do not answer."""
        unit = self.read_px4_unit_torques(vehicle)
        if unit is not None:  # PX4's rate loop outputs torque in its allocator's units, not the hover margin's
            self.note("allocation", f"PX4 unit torque from CA_ROTOR*: {[round(float(u), 3) for u in unit]} N m")
        elif self.flavour == "px4":  # PX4 <= v1.13 (mixers) have no CA_ROTOR* parameters
            self.note("allocation", "no CA_ROTOR* parameters: unit torque taken as the vehicle's hover-margin torque")
        model = autopilot_model_from_params(
            self.flavour, self.conn.param_get, vehicle, unit, angle_boost_default, warn=self.warnings.append
        )
        self.note(
            "autopilot_model",
            f"attitude P {list(model.attitude_p)}, rate bandwidth {[round(b, 2) for b in model.rate_bandwidth]} 1/s, "
            f"rate I/P {[round(v, 3) for v in model.rate_integral]} 1/s, hover {model.hover_thrust_norm}, "
            f"angle boost {model.angle_boost}",
        )
        return model

    def read_tilt_limit(self) -> float | None:
        """The autopilot's own tilt limit, rad: PX4 MPC_TILTMAX_AIR (deg), ArduPilot ANGLE_MAX (cdeg); None when it
        does not answer."""
        if self.flavour == "px4":
            v = self.conn.param_get("MPC_TILTMAX_AIR")
            deg = v
        else:
            v = self.conn.param_get("ANGLE_MAX")
            deg = None if v is None else v / 100.0
        if deg is None or not (math.isfinite(deg) and 0.0 < deg < 90.0):
            return None
        return math.radians(deg)

    def read_px4_unit_torques(self, vehicle: Vehicle) -> tuple[float, float, float] | None:
        """PX4: the physical torque of a unit normalized torque through its allocator, from CA_ROTOR_COUNT and
        CA_ROTORn_PX / PY / CT / KM (``offboard.flight.px4_allocation``); None for ArduPilot, or when they do not
        answer."""
        if self.flavour != "px4":
            return None
        from offboard.flight.px4_allocation import unit_torques_from_params

        def get(name: str) -> float | None:  # the count first, with fewer retries: a PX4 without it is common
            if name == "CA_ROTOR_COUNT":
                return self.conn.param_get(name, timeout=0.3, retries=2)
            return self.conn.param_get(name)

        return unit_torques_from_params(get, vehicle)

    def read_hover_throttle(self) -> float | None:
        """The autopilot's hover throttle now (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER, which ArduPilot learns in
        flight: read before the take-off it is the bare vehicle's, 0.39 where the loaded vehicle needs 0.51), 0..1,
        or None when it does not answer."""
        name = "MPC_THR_HOVER" if self.flavour == "px4" else "MOT_THST_HOVER"
        h = self.conn.param_get(name)
        return h if h is not None and math.isfinite(h) and 0.0 < h < 1.0 else None

    def check_vehicle_constants(self, vehicle: Vehicle) -> None:
        """Compare the vehicle file with what the autopilot reports (the emulator's EMU_* parameters); a warning
        for each mismatch above 5 %, nothing if the autopilot has no such parameters."""
        pairs = {
            "EMU_MASS": vehicle.mass_vehicle,
            "EMU_LOAD_MASS": vehicle.mass_load,
            "EMU_CABLE_LEN": vehicle.cable_length,
            "EMU_THR_MAX": vehicle.thrust_max,
        }
        first = self.conn.param_get("EMU_MASS", timeout=0.3, retries=1)
        if first is None:
            return
        for name, mine in pairs.items():
            theirs = first if name == "EMU_MASS" else self.conn.param_get(name, timeout=0.3, retries=1)
            if theirs is not None and abs(theirs - mine) > 0.05 * max(abs(mine), 1e-9):
                self.warnings.append(f"vehicle file {name} = {mine:g} but the vehicle reports {theirs:g}")

    def ensure_ardupilot_thrust_mode(self) -> None:
        """ArduPilot: GUID_OPTIONS bit 3 so that SET_ATTITUDE_TARGET thrust is throttle; UserError if refused."""
        v = self.conn.param_get("GUID_OPTIONS")
        if v is None:
            raise UserError("ArduPilot did not answer GUID_OPTIONS: cannot make thrust a throttle")
        if int(v) & 8:
            self.note("guid_options", f"GUID_OPTIONS = {int(v)} (thrust is throttle)")
            return
        new = int(v) | 8
        self.conn.param_set("GUID_OPTIONS", new, 6)
        t_end = time.monotonic() + 2.0
        while time.monotonic() < t_end:
            self.conn.poll()
            if int(self.conn.params.get("GUID_OPTIONS", v)) & 8:
                self.note("guid_options", f"GUID_OPTIONS {int(v)} -> {new} (thrust is throttle)")
                return
            time.sleep(0.005)
        raise UserError("ArduPilot refused GUID_OPTIONS bit 3 (thrust as throttle); set it by hand")

    # ------------------------------------------------------------------------------------------ modes ---
    def set_mode(self, role: str, idle: Idle | None = None, retries: int = 5, rounds: int = 3) -> bool:
        """DO_SET_MODE to the flavour's mode for ``role`` (offboard, hold, land); True when accepted. The result
        (a MAV_RESULT, or None when nothing answered) is kept in :attr:`last_mode_result`.

        A command that is never acknowledged is not a refusal: on a lossy link (30 % each way, 5 tries) about one
        switch in 30 lost every command or every answer. Then the heartbeat decides, and if it does not show the
        mode the command is sent again, up to ``rounds`` times."""
        main, sub = MODES[self.flavour][role]
        res = None
        for _ in range(max(1, rounds)):
            res = self.conn.command(MAV_CMD_DO_SET_MODE, 1.0, float(main), float(sub), idle=idle, retries=retries)
            if res is not None:
                break
            if self.wait_for(lambda: self.in_mode(role), 1.5, idle):  # no acknowledgement: believe the heartbeat
                res = MAV_RESULT_ACCEPTED
                break
        self.last_mode_result = res
        self.note("set_mode", f"{role} ({main}, {sub}): result {res}")
        return res == MAV_RESULT_ACCEPTED

    def send_mode_no_wait(self, role: str) -> None:
        """DO_SET_MODE without waiting for the answer (failsafes: the link may be gone)."""
        main, sub = MODES[self.flavour][role]
        self.conn.command_long(MAV_CMD_DO_SET_MODE, 1.0, float(main), float(sub))

    def in_mode(self, role: str) -> bool:
        """Whether the last heartbeat shows the role's mode."""
        v = self.conn.vehicle
        return v is not None and v.custom_mode == custom_mode(self.flavour, role)

    def wait_for(self, pred: Callable[[], bool], timeout: float, idle: Idle | None = None) -> bool:
        """Poll until ``pred()`` (True) or ``timeout`` s (False), calling ``idle`` meanwhile."""
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            self.conn.poll()
            if pred():
                return True
            if idle is not None:
                idle()
            time.sleep(0.002)
        return False

    # --------------------------------------------------------------------------------------- arm / fly ---
    def arm(self, idle: Idle | None = None, timeout: float = 10.0) -> None:
        """Arm (retrying while the autopilot says 'temporarily rejected', e.g. no position yet); UserError."""
        t_end = time.monotonic() + timeout
        last = None
        while time.monotonic() < t_end:
            last = self.conn.command(MAV_CMD_COMPONENT_ARM_DISARM, 1.0, 0.0, idle=idle)
            if last == MAV_RESULT_ACCEPTED:
                self.armed_here = True
                self.note("arm", "armed")
                return
            self.wait_for(lambda: False, 0.25, idle)
        why = "; ".join(self.conn.statustexts[-3:])
        raise UserError(f"the autopilot refused to arm (result {last}){': ' + why if why else ''}")

    def disarm(self, idle: Idle | None = None) -> bool:
        """Disarm (not forced: only on the ground)."""
        res = self.conn.command(MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 0.0, idle=idle)
        self.note("disarm", f"result {res}")
        return res == MAV_RESULT_ACCEPTED

    def takeoff(
        self,
        height: float,
        home_alt_amsl: float | None,
        height_now: Callable[[], float | None],
        idle: Idle | None = None,
        timeout: float = 60.0,
    ) -> None:
        """Arm and climb to ``height`` m above home with the autopilot's own take-off; UserError on failure.

        height_now: the current height above home (m, from telemetry), None while unknown.
        """
        fl = self.flavour
        if fl == "ardupilot" and not self.set_mode("offboard", idle=idle):  # GUIDED
            raise UserError("ArduPilot refused GUIDED mode")
        self.arm(idle=idle)

        def send() -> int | None:
            if fl == "px4":
                alt = (home_alt_amsl if home_alt_amsl is not None else 0.0) + height
                return self.conn.command(MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, alt, idle=idle)
            return self.conn.command(MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, height, idle=idle)

        def climbing() -> bool:
            h = height_now()
            return h is not None and h > TAKEOFF_CLIMB_M

        res = send()
        for _ in range(TAKEOFF_RESENDS):
            # no acknowledgement (lossy link): the command or only its ACK was lost, and the climb tells which; a
            # vehicle that has not started climbing gets the command again (a second take-off command while taking
            # off is harmless on PX4 and ArduPilot; a lost one left the vehicle on the ground until the time-out:
            # tests/test_loop_failsafe.py at 30 % loss, CI 2026-12-06)
            if res is not None or self.wait_for(climbing, TAKEOFF_CLIMB_WAIT_S, idle):
                break
            res = send()
        if res is None:
            self.warnings.append("take-off command not acknowledged; waiting for the climb")
        elif res != MAV_RESULT_ACCEPTED:
            raise UserError(f"take-off refused (result {res}): " + "; ".join(self.conn.statustexts[-3:]))
        self.note("takeoff", f"to {height:.2f} m above home (result {res})")
        self.wait_for_takeoff(height, height_now, timeout, idle)

    def wait_for_takeoff(
        self, height: float, height_now: Callable[[], float | None], timeout: float, idle: Idle | None = None
    ) -> None:
        """Wait until the vehicle is within 0.1 m of ``height`` (m above home); UserError after ``timeout`` s."""

        def reached() -> bool:
            h = height_now()
            return h is not None and h >= height - 0.1

        if not self.wait_for(reached, timeout, idle):
            raise UserError(f"take-off did not reach {height:.2f} m within {timeout:g} s")
        self.note("takeoff_done", f"height {height_now():.2f} m")


__all__ = ["MODES", "OPTIONAL_STREAMS", "ManagementEvent", "Manager", "custom_mode"]
