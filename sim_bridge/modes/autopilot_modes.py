"""The emulated autopilot's modes, arming and failsafes: mode changes and their refusals, arming
checks, the offboard-loss and guided-timeout failsafes, auto-disarm, and the mode logic that turns the current
mode into an attitude / thrust target (250 Hz, in ``_outer``).

A mixin: it works on the attributes :class:`sim_bridge.autopilot.Autopilot` sets up (one autopilot, split by
role so that each file has one job); it is not used on its own.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

from estimators.model.frames import (
    frd_to_model_body,
)
from sim_bridge.autopilot_constants import (
    ACCEPTED,
    AP_FORCE_ARM,
    CRITICAL,
    EMERGENCY,
    FAILED,
    INFO,
    PX4_FORCE,
    PX4_OBL_ACTIONS,
    TEMPORARILY_REJECTED,
    WARNING,
    all_finite,
)
from sim_bridge.inner.airframe import (
    angle_boost,
    ardupilot_climb_rate,
    ardupilot_throttle_newtons,
    px4_thrust_newtons,
)
from sim_bridge.modes.flavors import Mode

log = logging.getLogger("sim_bridge.autopilot")


class ModeLogic:
    """Modes, arming, failsafes and per-mode targets of :class:`sim_bridge.autopilot.Autopilot`."""

    # ================================================================== modes
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
        refused = ("offboard" in self.refuse and mode.kind in ("offboard", "guided")) or (
            "takeoff" in self.refuse and mode.kind == "takeoff"
        )
        if refused:  # --refuse: the mode's entry check fails, answered as each autopilot answers it
            if self.fl.is_px4:  # Commander's printRejectMode and TEMPORARILY_REJECTED
                return False, TEMPORARILY_REJECTED, f"Switching to {mode.name} is currently not possible"
            return False, FAILED, "Flight mode change failed"
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
            if "arm" in self.refuse:  # --refuse arm: a sensor check that keeps failing
                reason = "Preflight Fail: Accel Sensor 0 missing" if px4 else "PreArm: 3D Accel calibration needed"
            elif self.t_us < self.est_ready_us:
                reason = "Preflight Fail: ekf2 missing data" if px4 else "PreArm: Need Position Estimate"
            elif not self.mode.armable:
                reason = f"Arming denied: not allowed in {self.mode.name}" if px4 else "Arm: Mode not armable"
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
        self.px4_rate.reset_integral()
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
                    if px4:  # PX4 hands normalized torques to its allocator
                        self.direct_tau = (c[0], c[1], c[2])
                    else:
                        t_frd = (c[0] * self.att.tmax[0], c[1] * self.att.tmax[1], c[2] * self.att.tmax[2])
                        self.direct_tau = frd_to_model_body(*t_frd)
                    self.thrust_cmd = c[3] * self.tmax
                    self.q_sp = self._q_now(x)
                    return
                if sk == "pos":
                    self._fly_position_setpoint(x, dt, on_ground)
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
            climb = self._pilot_climb_rate() if self.mode.name in ("LOITER", "POSHOLD") else 0.0
            if climb != 0.0:  # ArduPilot's LOITER / POSHOLD follow the throttle stick (low stick: descend, land)
                z = self.hold_pos[2] if self.hold_pos[2] is not None else x[2]
                self.hold_pos = (self.hold_pos[0], self.hold_pos[1], min(max(z + climb * dt, -0.5), x[2] + 2.0))
                if on_ground and climb < 0.0:
                    self._idle(x)
                    return
            self._position(x, self.hold_pos, (0.0, 0.0, climb), self.hold_yaw, dt, on_ground)
        elif kind == "althold":
            climb = self._pilot_climb_rate() if not self.fl.is_px4 else 0.0
            if climb != 0.0:  # ArduPilot's ALT_HOLD: the stick sets the climb rate
                self.z_target = min(max(self.z_target + climb * dt, -0.5), x[2] + 2.0)
            self._althold(x, self.z_target, climb, self.hold_yaw, dt, on_ground)
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
            self._position(
                x, (self.hold_pos[0], self.hold_pos[1], alt), (0.0, 0.0, 0.0), self.hold_yaw, dt, False, z_up=up
            )
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
                thrust_n = ardupilot_throttle_newtons(
                    thrust, x[6], x[7], bool(int(self._p("ATC_ANGLE_BOOST"))), self.tmax
                )
            else:
                climb = ardupilot_climb_rate(
                    thrust, self._p("WPNAV_SPEED_UP") / 100.0, self._p("WPNAV_SPEED_DN") / 100.0
                )
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
            self._fly_position_setpoint(x, dt, on_ground)
            return
        if sub == "takeoff":
            self._position(x, self.hold_pos, (0.0, 0.0, 0.0), self.hold_yaw, dt, False)
            if x[2] >= self.takeoff_alt - 0.1:
                self.guided_sub = "hold"  # ArduPilot's GUIDED keeps the take-off's target altitude
                self._hold_altitude(self.takeoff_alt)
            return
        self._position(x, self.hold_pos, (0.0, 0.0, 0.0), self.hold_yaw, dt, on_ground)

    def _fly_position_setpoint(self, x: Sequence[float], dt: float, on_ground: bool) -> None:
        """The position setpoint received (PX4 OFFBOARD, ArduPilot GUIDED), its velocity as feed-forward, at its yaw
        or, when it gives none, at the heading held."""
        yaw = self.sp_yaw if self.sp_yaw is not None else self.hold_yaw
        self._position(x, self.sp_pos, self.sp_vel, yaw, dt, on_ground)

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

    _pilot_mode: Mode | None = None

    def pilot_switch(self, mode_name: str) -> None:
        """A pilot's RC mode switch (for tests; thread-safe): the autopilot enters ``mode_name`` at its next plant
        step on its own, as a real one does on an RC channel: no command, no COMMAND_ACK, only the HEARTBEAT
        shows it. KeyError for a mode the flavour does not have."""
        self._pilot_mode = self.fl.by_name[mode_name]

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

    def _cmd_takeoff(self, p7: float) -> int:
        if not self.armed:
            self.statustext(CRITICAL, "Takeoff denied: disarmed" if self.fl.is_px4 else "Takeoff: not armed")
            return TEMPORARILY_REJECTED if self.fl.is_px4 else FAILED
        if self.fl.is_px4:
            alt = (p7 - self.home.alt) if all_finite(p7) else self._p("MIS_TAKEOFF_ALT")
            r = self.request_mode(self.fl.by_name["AUTO.TAKEOFF"])
            if r == ACCEPTED:
                self.takeoff_alt = max(alt, 0.5)
            return r
        if self.mode.kind != "guided" or not all_finite(p7) or p7 <= 0.0 or "takeoff" in self.refuse:
            return FAILED  # ArduPilot's do_user_takeoff failed: MAV_RESULT_FAILED, no message
        self.guided_sub = "takeoff"
        self.takeoff_alt = p7
        self.hold_pos = (self.x[0], self.x[1], p7)
        return ACCEPTED

    # ---------------------------------------------------------------- other messages

    def _pilot_climb_rate(self) -> float:
        """ArduPilot's climb rate from the throttle stick (m/s up): zero inside THR_DZ around mid stick, up to
        PILOT_SPEED_UP at full stick, down to PILOT_SPEED_DN (0: PILOT_SPEED_UP) at low stick. PX4: 0 (no RC)."""
        if self.fl.is_px4:
            return 0.0
        thr = self.rc_throttle
        dz = self._p("THR_DZ") / 1000.0
        lo, hi = 0.5 - dz, 0.5 + dz
        up = self._p("PILOT_SPEED_UP") / 100.0
        dn = (self._p("PILOT_SPEED_DN") or self._p("PILOT_SPEED_UP")) / 100.0
        if thr < lo:
            return -dn * (lo - thr) / lo
        if thr > hi:
            return up * (thr - hi) / (1.0 - hi)
        return 0.0
