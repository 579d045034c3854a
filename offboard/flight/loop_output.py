"""The live loop's outputs to the autopilot (mixed into :class:`offboard.flight.loop.FlightLoop`, whose state it
reads and writes): each setpoint encoded, checked and written (a refused one replaced by hover), the position goal
before control, and the hand-over at the end: hold / land requested while hover setpoints keep streaming, paced,
until the autopilot confirms; a disarm on the ground after a refused take-off.
"""

from __future__ import annotations

import gc
import logging
import select
import time
from typing import Any

from estimators.model.frames import model_euler_to_ned, model_to_ned_vector
from offboard.flight.link.setpoints import SetpointError, encode, encode_position
from offboard.flight.loop_link import FlightAbortError
from offboard.flight.supervisor import mode_name

#: the loop's one logger: ``offboard.flight.status`` treats its records as loop events
log = logging.getLogger("offboard.flight.loop")


class LoopOutputs:
    """The outputs of :class:`~offboard.flight.loop.FlightLoop` (a mixin: the state is the loop's)."""

    def _send(self, sp: Any, t: float, log: bool = True) -> bytes:
        """Encode, check and write setpoint ``sp`` (sender time ``t``, s); the bytes written. ``log=False``: the
        caller logs them (``conn.log_sent``) after the time-critical part of the tick."""
        try:
            msg = encode(self.conn.mav, sp, max(t, 0.0), *self.target)
        except SetpointError as exc:  # the mapper should make this impossible; never send it anyway
            self.event("setpoint_refused", str(exc))
            sp = self.mapper.hover_setpoint(self.last_att.psi if self.last_att else 0.0)
            msg = encode(self.conn.mav, sp, max(t, 0.0), *self.target)
        buf = self.conn.send(msg, log)
        self.stats.sent_bytes += len(buf)
        self.last_sp = sp
        self.last_send_local = time.monotonic()
        return buf

    def _hover_sp(self) -> Any:
        return self.mapper.hover_setpoint(self.last_att.psi if self.last_att is not None else 0.0)

    def _send_goal(self) -> None:
        assert self.goal is not None
        x, y, z, psi = self.goal
        n, e, d = model_to_ned_vector(x, y, z)
        yaw = model_euler_to_ned(0.0, 0.0, psi)[2]
        self.stats.sent_bytes += len(
            self.conn.send(encode_position(self.conn.mav, n, e, d, yaw, self.t_vehicle, *self.target))
        )
        self.last_send_local = time.monotonic()

    def _abort_action(self, ab: FlightAbortError) -> str:
        """What an abort hands the vehicle over to: a watchdog's hold becomes a landing under ``--end land`` (the
        user asked for the flight to end on the ground); a signal follows ``--on-signal``; ``none`` stays none."""
        if ab.action == "hold" and ab.kind != "signal" and self.cfg.end_action == "land":
            return "land"
        return ab.action

    def _disarm_if_on_the_ground(self) -> None:
        """After a refusal that left the vehicle armed where it stood (the take-off refused): disarm it (not
        forced: the autopilot itself checks that it is landed). In the air (offboard refused after the take-off)
        nothing: it holds."""
        h = self.height()
        if h is None or h > 0.3:
            return
        try:
            ok = self.mgr.disarm(idle=self._read)
        except Exception as exc:  # the hand-over is already reported; do not mask the refusal
            log.exception("disarm after a refusal failed")
            self.event("exit_failed", f"disarm: {type(exc).__name__}: {exc}")
            return
        self.event("exit_done", "disarmed on the ground" if ok else "disarm refused by the autopilot")

    def _finish_guarded(self, action: str, reason: str) -> str:
        """:meth:`_finish`, and if the hand-over itself fails (the link is gone, the socket refuses), say so."""
        try:
            return self._finish(action, reason)
        except Exception as exc:  # the flight is already ending: report, do not mask the cause
            log.exception("the hand-over failed")
            self.event("exit_failed", f"{type(exc).__name__}: {exc}")
            return f"{action} requested, hand-over failed ({type(exc).__name__}: {exc})"

    def _control_ended(self) -> None:
        """After the exit is recorded (and the hold / land requested): gaps and the autopilot's target are no longer
        judged, and the refusals the rate limit held back are told."""
        self.staleness.stop()
        self._echo_on = False
        self._enable_gc()
        self._report_dropped(final=True)

    def _enable_gc(self) -> None:
        """Turn the garbage collector back on if the control phase turned it off (once)."""
        if self._gc_to_enable:
            self._gc_to_enable = False
            gc.enable()

    def _finish(self, action: str, reason: str) -> str:
        """Leave offboard control: request hold / land while streaming hover setpoints, paced at the loop rate,
        until the heartbeat shows it (bounded by ``exit_timeout_s``, vehicle time in lockstep), then, for land,
        wait for the disarm. ``action`` ``none``: the vehicle has left the loop's control already (a pilot or a
        failsafe took over, or it disarmed): nothing is requested and nothing streamed."""
        self.supervisor.release()
        self._finishing = True
        if self.hover_learner is not None:  # a landing (the load touching down) is no hover to learn from
            self.hover_learner.stop()
        v = self.conn.vehicle
        if action == "none":
            mode = mode_name(self.mgr.flavour, v.custom_mode) if v is not None else "unknown"
            self.event("exit", f"left to the vehicle: {reason}")
            self._control_ended()  # what the rate limit held back (after the exit: it is not urgent)
            state = f"in {mode}, {'armed' if v is not None and v.armed else 'disarmed'} (not commanded by slung)"
            self.event("exit_done", state)
            return state
        role = "hold" if action == "hold" else "land"
        self.event("exit", f"{role}: {reason}")
        self.mgr.send_mode_no_wait(role)
        self._control_ended()
        lockstep = self.cfg.lockstep
        clock = self._now_vehicle if lockstep else time.monotonic
        t_end = clock() + self.cfg.exit_timeout_s
        wall_end = time.monotonic() + max(5.0 * self.cfg.exit_timeout_s, 10.0)  # a lockstep vehicle that stopped
        last_cmd = clock()
        n = 0
        while clock() < t_end and time.monotonic() < wall_end and not self.mgr.in_mode(role):
            self._send(self._hover_sp(), max(self.t_vehicle, self._now_vehicle() if lockstep else 0.0))
            n += 1
            self._pace_exit(lockstep)
            if clock() - last_cmd > 0.1:
                self.mgr.send_mode_no_wait(role)
                last_cmd = clock()
        state = role if self.mgr.in_mode(role) else f"{role} requested (not confirmed)"
        self.event("exit_done", f"{state} ({n} hover setpoints sent meanwhile)")
        if role == "land" and self.mgr.in_mode(role) and self.mgr.wait_for(lambda: v is not None and not v.armed, 30.0):
            state = "landed, disarmed"
            self.event("exit_done", state)
        return state

    def _pace_exit(self, lockstep: bool) -> None:
        """One period of the exit stream: in lockstep the vehicle's next step marker (the vehicle paces); in real
        time at least one loop period after the last setpoint, whatever arrives or whatever signal is pending."""
        if lockstep:
            self._wait(self.cfg.lockstep_wait_s)
            return
        t_next = (self.last_send_local or time.monotonic()) + self.period
        while True:
            self._read()
            left = t_next - time.monotonic()
            if left <= 0.0:
                return
            if self._fd is not None:
                select.select([self._fd], [], [], min(left, 0.05))
            else:
                time.sleep(min(left, 0.0005))
