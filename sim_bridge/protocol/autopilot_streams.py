"""The emulated autopilot's outgoing side: HEARTBEAT / SYS_STATUS contents, the stream scheduler
(SET_MESSAGE_INTERVAL, REQUEST_MESSAGE, lockstep rephasing and the end-of-step marker), the per-step timers and
the link-error reports.

A mixin: it works on the attributes :class:`sim_bridge.autopilot.Autopilot` sets up (one autopilot, split by
role so that each file has one job); it is not used on its own.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from estimators.model.frames import (
    model_body_to_frd,
    model_quaternion_to_ned,
)
from sim_bridge.autopilot_constants import (
    ACCEPTED,
    DENIED,
    TEMPORARILY_REJECTED,
    WARNING,
    all_finite,
)
from sim_bridge.modes.flavors import SAFETY_ARMED
from sim_bridge.protocol.messages import BUILDERS, NEEDS_POSITION, msg_load_attitude, msg_load_global_position_int

log = logging.getLogger("sim_bridge.autopilot")


class TelemetryStreams:
    """Telemetry streams and per-step bookkeeping of :class:`sim_bridge.autopilot.Autopilot`."""

    def statustext(self, severity: int, text: str) -> None:
        """Send a STATUSTEXT (truncated to 50 characters) from the autopilot."""
        self.counters["statustexts"] += 1
        self.mav.send(self.mav.statustext_encode(severity, text.encode()[:50]))

    # ================================================================== incoming

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
        return mav.sys_status_encode(
            sensors,
            sensors,
            sensors,
            100,
            12600,
            -1,
            100,
            min(drop, 10000),
            min(bad, c),
            min(rx.unsigned_rejected + rx.bad_signature, c),
            min(rx.foreign_target, c),
            min(rx.garbage_datagrams, c),
            min(self.counters["setpoints_rejected"], c),
        )

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

    def _cmd_message_interval(self, msgid: float, interval: float) -> int:
        if not all_finite(msgid, interval):
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
        if not all_finite(msgid):
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

    def after_step(self, t_us: int, x: Sequence[float], u: Sequence[float], on_ground: bool) -> None:
        """Telemetry that came due, timers and auto-disarm; called after every plant step."""
        if self._pilot_mode is not None:
            mode, self._pilot_mode = self._pilot_mode, None
            self._set_mode(mode)
        self.t_us = t_us
        self.k += 1
        self.x_true = x
        if self.ekf is not None:
            if self.k % 10 == 0:  # the error wanders over seconds: 100 Hz is plenty
                self.ekf.step(10 * self.dt, (x[0], x[1], x[2]), on_ground, yaw=x[8])
            self.x = self._believed(x)
        else:
            self.x = x
        if self.k % 10 == 0:  # ArduPilot's hover-throttle learning runs at 100 Hz
            self._learn_hover(self.x, 10 * self.dt)
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
                    msg = BUILDERS[name](self.mav, snap, self)
                    if msg is not None:  # (a builder may have nothing to say: ESTIMATOR_STATUS without --ekf)
                        self.mav.send(msg)
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
        snap = self.tel.snapshot(self.t_us, self.x_true, self.u, self.on_ground)
        msg = BUILDERS[name](mav, snap, self)
        if msg is not None:
            mav.send(msg)

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

    def _send_autopilot_version(self) -> None:
        self.mav.send(
            self.mav.autopilot_version_encode(
                self.fl.capabilities, self.fl.version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5157, [0] * 18
            )
        )
