"""Supervision of the vehicle during offboard control: does the autopilot still do what the loop asked?

The loop asks for one mode (OFFBOARD on PX4, GUIDED on ArduPilot) and an armed vehicle. Anything else the
vehicle reports while the loop is in control ends the flight, with its reason:

- ``mode_change``: a HEARTBEAT of the autopilot shows another mode than the one the loop asked for, after the
  requested mode was seen (a pilot's RC mode switch, a ground station's DO_SET_MODE / SET_MODE, an autopilot
  failsafe). A pilot taking over is a normal end, but never a "completed" flight: the loop stops streaming and
  leaves the vehicle in the mode it is in (it does not fight the pilot by requesting hold);
- ``disarmed``: the vehicle disarmed (a forced disarm, a kill switch, a crash detector), seen through whichever
  tells first: a HEARTBEAT without MAV_MODE_FLAG_SAFETY_ARMED (1 Hz: up to a second late), the autopilot's own
  STATUSTEXT ("Disarmed by ...", "Disarming motors"), the acknowledgement of another sender's accepted
  MAV_CMD_COMPONENT_ARM_DISARM (the vehicle is armed in flight: an accepted arm/disarm command from someone else
  is the disarm), or SYS_STATUS's motor outputs no longer enabled (once they were seen enabled). The loop then
  stops at once and asks nothing of the vehicle: a hold request to a disarmed vehicle lying on the ground would
  re-arm nothing and mean nothing. EXTENDED_SYS_STATE's landed state is not taken for a disarm: an armed vehicle
  that touches the ground reads ON_GROUND too (a loaded-machine emulator flight did, 7 Dec 2026: taken for a
  disarm, it was left armed in OFFBOARD with no setpoint stream);
- ``mode_not_entered``: the requested mode was acknowledged but no HEARTBEAT has shown it: after ``confirm_s``
  (HEARTBEAT is a 1 Hz message on both autopilots, so the default is 3 s) once at least two heartbeats of the
  autopilot have arrived since the request without it, or after ``confirm_max_s`` (9 s) whatever arrived. A
  heartbeat that is lost says nothing: on a link losing 30 % of packets three 1 Hz heartbeats in a row are lost
  about once in 37 starts (0.3^3), and the time-out alone then ended a flight that was in the mode; nine in a row,
  about once in 50 000. Meanwhile the loop streams its setpoints, which a vehicle not in the mode ignores (it holds
  where it is, and the tracking watchdog still ends the flight);
- ``tracking_error``: the load's position error (estimated flat output against the reference) above
  ``tracking_limit_m``; the vehicle is then handed to its hold mode by the loop. Its default scales with the line
  (:func:`tracking_limit_for`): a load on 30 m moves metres for a swing the swing watchdog allows.

STATUSTEXT and COMMAND_ACK messages are recorded as they arrive (``notes``): the autopilot's own words (e.g.
"Failsafe activated: offboard signal lost") and acknowledgements of commands the loop did not send (a
COMMAND_ACK whose ``target_system`` / ``target_component`` is another sender: someone else is commanding the
vehicle). The newest of them is quoted in a mode-change or disarm reason.

The supervisor is fed the autopilot's messages by the loop (:meth:`observe`, HEARTBEAT / STATUSTEXT /
COMMAND_ACK / SYS_STATUS only) and asked once per tick (:meth:`check`); it never sends
anything. Times are local monotonic seconds (the caller's clock: vehicle time in lockstep).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_RESULT_ACCEPTED = 0
#: SYS_STATUS onboard_control_sensors_*: motor outputs / control
MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS = 0x8000

#: the autopilots' own words for a disarm (PX4 "Disarmed by external command" / "by landing" / "by kill switch",
#: ArduPilot "Disarming motors"); refusals ("Disarming denied: not landed") do not match
DISARM_TEXT = re.compile(r"^\s*(disarmed\b|disarming motors\b)", re.IGNORECASE)

#: the messages the supervisor reads (:meth:`Supervisor.observe`)
SUPERVISED_MESSAGES = frozenset(("HEARTBEAT", "STATUSTEXT", "COMMAND_ACK", "SYS_STATUS"))

#: exit codes of ``slung fly`` / ``slung demo`` by how the flight ended (docs/usage-fly-demo.md)
EXIT_COMPLETED = 0
EXIT_ABORTED = 1  # a watchdog, a signal or an internal fault ended the flight (vehicle handed to hold / land)
EXIT_USER_ERROR = 2  # bad input or a refusal before the flight (estimators.errors.UserError)
EXIT_TAKEN_OVER = 3  # the vehicle left offboard control without being asked (pilot, ground station, failsafe)
EXIT_DISARMED = 4  # the vehicle disarmed in flight without being asked

#: ``ended_by`` -> exit code; anything not listed (every watchdog, signal, internal_error) is EXIT_ABORTED
EXIT_CODES: dict[str, int] = {
    "completed": EXIT_COMPLETED,
    "mode_change": EXIT_TAKEN_OVER,
    "mode_not_entered": EXIT_TAKEN_OVER,
    "disarmed": EXIT_DISARMED,
}

#: HEARTBEAT.custom_mode -> name, for reasons (PX4: main << 16 | sub << 24; ArduPilot Copter: the number)
PX4_MODE_NAMES = {
    1 << 16: "MANUAL",
    2 << 16: "ALTCTL",
    3 << 16: "POSCTL",
    (4 << 16) | (1 << 24): "AUTO.READY",
    (4 << 16) | (2 << 24): "AUTO.TAKEOFF",
    (4 << 16) | (3 << 24): "AUTO.LOITER",
    (4 << 16) | (4 << 24): "AUTO.MISSION",
    (4 << 16) | (5 << 24): "AUTO.RTL",
    (4 << 16) | (6 << 24): "AUTO.LAND",
    (4 << 16) | (8 << 24): "AUTO.FOLLOW_TARGET",
    (4 << 16) | (9 << 24): "AUTO.PRECLAND",
    5 << 16: "ACRO",
    6 << 16: "OFFBOARD",
    7 << 16: "STABILIZED",
}
ARDUPILOT_MODE_NAMES = {
    0: "STABILIZE",
    1: "ACRO",
    2: "ALT_HOLD",
    3: "AUTO",
    4: "GUIDED",
    5: "LOITER",
    6: "RTL",
    7: "CIRCLE",
    9: "LAND",
    11: "DRIFT",
    13: "SPORT",
    15: "AUTOTUNE",
    16: "POSHOLD",
    17: "BRAKE",
    18: "THROW",
    20: "GUIDED_NOGPS",
    21: "SMART_RTL",
}


#: the vehicle's share of the default tracking limit, m (the whole limit before lines longer than 1 m were flown)
TRACKING_VEHICLE_M = 2.0


def tracking_limit_for(cable_length: float, swing_limit_rad: float) -> float:
    """The default load-position error that ends a flight, m: ``TRACKING_VEHICLE_M`` for the vehicle plus what a
    swing up to the swing watchdog's limit moves the load, ``l sin(swing_limit)``. The swing itself is the swing
    watchdog's to judge; this one catches the vehicle leaving the reference. A fixed 2 m ended every flight of a
    10-30 m line whose load swung 0.07-0.2 rad (0.7-6 m), e.g. a take-over of a swinging load.
    ``cable_length``: m; ``swing_limit_rad``: rad."""
    return TRACKING_VEHICLE_M + cable_length * math.sin(min(swing_limit_rad, 0.5 * math.pi))


def exit_code(ended_by: str) -> int:
    """The process exit code for a flight that ended by ``ended_by`` (``FlightResult.ended_by``)."""
    return EXIT_CODES.get(ended_by, EXIT_ABORTED)


def mode_name(flavour: str, custom_mode: int) -> str:
    """A readable name of a HEARTBEAT custom_mode (the number when unknown)."""
    names = PX4_MODE_NAMES if flavour == "px4" else ARDUPILOT_MODE_NAMES
    return names.get(custom_mode, f"custom mode {custom_mode}")


@dataclass(frozen=True)
class Verdict:
    """Why the supervisor ends the flight: ``kind`` (``mode_change``, ``disarmed``, ``mode_not_entered``,
    ``tracking_error``), a one-line reason, and what the loop does: ``hold`` (hand over to the hold mode) or
    ``none`` (the vehicle is already out of the loop's hands: stop streaming, request nothing)."""

    kind: str
    reason: str
    action: str


@dataclass
class Note:
    """A STATUSTEXT or a foreign COMMAND_ACK seen during supervision (local time s, kind, text)."""

    t: float
    kind: str
    text: str


@dataclass
class Supervisor:
    """Watches the autopilot's HEARTBEAT, STATUSTEXT and COMMAND_ACK during offboard control (module docstring).

    flavour: ``px4`` / ``ardupilot``; own_ids: our (system, component) as the autopilot addresses its answers;
    own_systems: further systems of ours, any component (the MAVSDK backend's own instance);
    tracking_limit_m: the load's position error that ends the flight (m); confirm_s: how long an acknowledged
    mode may stay unseen in the HEARTBEAT once two heartbeats have arrived without it (s); confirm_max_s: how
    long it may stay unseen when heartbeats are lost (s).
    """

    flavour: str
    own_ids: tuple[int, int]
    tracking_limit_m: float = 2.0
    own_systems: tuple[int, ...] = ()
    confirm_s: float = 3.0
    confirm_max_s: float = 9.0
    notes: list[Note] = field(default_factory=list)
    foreign_acks: int = 0
    _expected: int | None = None
    _since: float = 0.0
    _confirmed: bool = False
    _mode: int | None = None
    _armed: bool | None = None
    _heartbeats: int = 0  # the autopilot's heartbeats since expect()
    #: the first sign of a disarm other than the heartbeat (what said so), None while none came
    _disarm_seen: str | None = None
    _motors_enabled_seen: bool = False

    # ------------------------------------------------------------------------------------------ control ---
    def expect(self, custom_mode: int, now: float) -> None:
        """From now on the vehicle must be armed and in ``custom_mode`` (HEARTBEAT encoding)."""
        self._expected, self._since, self._confirmed = custom_mode, now, False
        self._heartbeats = 0
        self._disarm_seen = None

    def release(self) -> None:
        """The loop hands the vehicle back (hold / land requested): stop supervising."""
        self._expected = None

    @property
    def active(self) -> bool:
        """True while a mode is expected."""
        return self._expected is not None

    # ------------------------------------------------------------------------------------------- input ---
    def observe(self, msg: Any, now: float) -> None:
        """One message of the autopilot's system: HEARTBEAT (autopilot component only), STATUSTEXT, COMMAND_ACK;
        anything else is ignored."""
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.autopilot == 8:  # MAV_AUTOPILOT_INVALID: a gimbal, camera, companion... not the autopilot
                return
            self._mode = int(msg.custom_mode)
            self._armed = bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
            self._heartbeats += 1
            if self._expected is not None and self._mode == self._expected and self._armed:
                self._confirmed = True
        elif kind == "STATUSTEXT":
            text = msg.text.decode("ascii", "replace") if isinstance(msg.text, bytes) else str(msg.text)
            text = text.rstrip("\x00").strip()
            self.notes.append(Note(now, "statustext", f"STATUSTEXT severity {msg.severity}: {text}"))
            if DISARM_TEXT.match(text):
                self._saw_disarm(f'the autopilot said "{text}"')
        elif kind == "COMMAND_ACK":
            ts = getattr(msg, "target_system", 0) or 0
            tc = getattr(msg, "target_component", 0) or 0
            if (ts, tc) != (0, 0) and (ts, tc) != self.own_ids and ts not in self.own_systems:
                self.foreign_acks += 1
                text = f"command {msg.command} from system {ts} component {tc} acknowledged (result {msg.result})"
                self.notes.append(Note(now, "foreign_command", text))
                if msg.command == MAV_CMD_COMPONENT_ARM_DISARM and msg.result == MAV_RESULT_ACCEPTED:
                    self._saw_disarm(f"an arm/disarm command from system {ts} component {tc} was accepted")
        elif kind == "SYS_STATUS" and msg.onboard_control_sensors_present & MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS:
            if msg.onboard_control_sensors_enabled & MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS:
                self._motors_enabled_seen = True
            elif self._motors_enabled_seen:
                self._saw_disarm("SYS_STATUS shows the motor outputs disabled")

    def _saw_disarm(self, what: str) -> None:
        """Keep the first sign of a disarm while supervising (before: the loop's own arming, not a fault)."""
        if self._expected is not None and self._disarm_seen is None:
            self._disarm_seen = what

    # ------------------------------------------------------------------------------------------ checks ---
    def check(self, now: float) -> Verdict | None:
        """A verdict if the vehicle no longer does what the loop asked, else None (cheap: once per tick)."""
        exp = self._expected
        if exp is None:
            return None
        recent = "; ".join([n.text for n in self.notes if n.t >= self._since][-2:])
        why = f" (last reports: {recent})" if recent else ""
        if self._disarm_seen is not None or (self._confirmed and self._armed is False):
            what = self._disarm_seen or "the heartbeat shows it disarmed"
            return Verdict("disarmed", f"the vehicle disarmed during offboard control: {what}{why}", "none")
        if self._confirmed:
            if self._mode != exp:
                name = mode_name(self.flavour, self._mode if self._mode is not None else -1)
                return Verdict(
                    "mode_change",
                    f"the vehicle left {mode_name(self.flavour, exp)} for {name} without being asked "
                    f"(pilot, ground station or failsafe){why}",
                    "none",
                )
            return None
        waited = now - self._since
        n = self._heartbeats
        if (waited > self.confirm_s and n >= 2) or waited > self.confirm_max_s:
            seen = "no heartbeat" if self._mode is None else mode_name(self.flavour, self._mode)
            return Verdict(
                "mode_not_entered",
                f"{mode_name(self.flavour, exp)} acknowledged but not shown by the heartbeat within "
                f"{waited:.1f} s ({n} heartbeat{'' if n == 1 else 's'} since the request; last: {seen}, armed "
                f"{self._armed}){why}",
                "hold",
            )
        return None

    def check_tracking(self, ex: float, ey: float, ez: float) -> Verdict | None:
        """A verdict if the load's position error (m, model frame) exceeds the limit. A non-finite error is not
        judged here: a non-finite estimate ends the flight through the divergence watchdog, a non-finite reference
        sample is replaced by the command mapping's fallback."""
        e = math.sqrt(ex * ex + ey * ey + ez * ez)
        if not e > self.tracking_limit_m:  # within the limit, or NaN
            return None
        return Verdict(
            "tracking_error", f"load position error {e:.2f} m above the limit {self.tracking_limit_m:g} m", "hold"
        )

    def summary(self) -> dict[str, Any]:
        """The ``supervision`` block of metrics.json."""
        return {
            "tracking_limit_m": self.tracking_limit_m,
            "confirm_s": self.confirm_s,
            "foreign_command_acks": self.foreign_acks,
            "statustexts": sum(1 for n in self.notes if n.kind == "statustext"),
        }


__all__ = [
    "EXIT_ABORTED",
    "EXIT_CODES",
    "EXIT_COMPLETED",
    "EXIT_DISARMED",
    "EXIT_TAKEN_OVER",
    "EXIT_USER_ERROR",
    "SUPERVISED_MESSAGES",
    "TRACKING_VEHICLE_M",
    "Note",
    "Supervisor",
    "Verdict",
    "exit_code",
    "mode_name",
    "tracking_limit_for",
]
