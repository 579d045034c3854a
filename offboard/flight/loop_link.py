"""The live loop's link and supervision (mixed into :class:`offboard.flight.loop.FlightLoop`, whose state it reads
and writes): reading the connection and routing each message (telemetry to the filter, HEARTBEAT / STATUSTEXT /
COMMAND_ACK to the supervisor, TIMESYNC to the latency measurement, the lockstep markers), waiting for a trigger, the
vehicle clock, the per-tick watchdogs (stale telemetry, supervision's verdict, the link's latency) and the signal
handlers. A watchdog ends the flight by raising :class:`FlightAbortError`.
"""

from __future__ import annotations

import contextlib
import math
import select
import signal
import time
from typing import Any

from estimators.model.measurements import Attitude, Imu, LoadAngle, PositionVelocity, ReportedAccuracy
from offboard.flight.link.connection import MavConnection
from offboard.flight.loop_records import LoopEvent
from offboard.flight.setpoint_echo import ATTITUDE_IGNORE
from offboard.flight.staleness import WATCHED
from offboard.flight.supervisor import SUPERVISED_MESSAGES, Verdict


class FlightAbortError(Exception):
    """Ends the flight: ``kind`` (the ``ended_by`` of the result), ``reason`` (one line), ``action`` (what the
    vehicle is handed over to: hold, land or none)."""

    def __init__(self, kind: str, reason: str, action: str = "hold") -> None:
        super().__init__(reason)
        self.kind, self.reason, self.action = kind, reason, action


class LinkSupervision:
    """The link side of :class:`~offboard.flight.loop.FlightLoop` (a mixin: the state is the loop's)."""

    def _read(self) -> bool:
        """Read everything waiting; True if a trigger message (ATTITUDE in real time, the lockstep marker)
        arrived since the last call (also through management's own polling)."""
        self.conn.poll()
        trig = self._triggered
        self._triggered = False
        return trig

    def _on_received(self, batch: list[Any]) -> None:
        """Listener of the connection: decode and push every message of the autopilot's system."""
        for r in batch:
            msg = r.msg
            if msg.get_srcSystem() != self.target[0]:
                continue
            kind = msg.get_type()
            if kind in SUPERVISED_MESSAGES:
                if kind != "HEARTBEAT" or msg.get_srcComponent() == self.target[1]:
                    self._supervise(msg)
                continue
            if kind == "TIMESYNC":
                if msg.tc1 != 0:
                    self._on_timesync(msg, r.t_local)
                continue
            if kind == "SYSTEM_TIME" and self.cfg.lockstep:
                self.marker_t = msg.time_boot_ms * 1e-3
                self.trigger_local = r.t_local
                self._triggered = True
                continue
            if kind == "ATTITUDE_TARGET":
                self._on_attitude_target(msg)
                continue
            if kind == "GLOBAL_POSITION_INT":
                self._on_global_position(msg, r.t_local)
                continue
            m = self.decoder.decode(msg)
            if m is None:
                continue
            if self._inject and isinstance(m, Attitude) and self._injected("measurement", m.t - self._t0_meas):
                m = m._replace(phi=math.nan)
            name = type(m).__name__
            self.last_rx_local[name] = r.t_local
            if name in WATCHED:
                gap = self.staleness.on_sample(name, m.t if self.cfg.lockstep else r.t_local)
                if gap is not None:
                    limit = self.staleness.limit_s
                    # longer than the limit and still flying: the loop itself stalled and read the gap late
                    late = " (the loop itself was stalled past the limit)" if gap > limit else ""
                    self.event(
                        "telemetry_gap",
                        f"no {name} telemetry for {gap * 1e3:.0f} ms: bridged on the filter's prediction "
                        f"(staleness limit {limit * 1e3:.0f} ms){late}",
                    )
            if not isinstance(m, ReportedAccuracy):  # (its stamp is not always a sample time: GPS_RAW_INT's)
                self.conn.clock.observe(m.t, r.t_local)
            if isinstance(m, Attitude):
                if math.isfinite(m.phi):
                    self.last_att = m
                    self._att_arrival = r.t_local
                if not self.cfg.lockstep:
                    self.trigger_local = r.t_local
                    self._triggered = True
            elif isinstance(m, PositionVelocity):
                self.last_pos = m
                self._z_samples.append(m.z)
            elif isinstance(m, LoadAngle):
                self.last_load = m
            elif isinstance(m, Imu) and self.hover_learner is not None:
                self.hover_learner.on_imu(m, self.last_att)
            if self.load_id is not None:
                self.load_id.push(m)
            if self.estimator_ready:
                self.estimator.push(m)
                self.n_meas += 1

    def _supervise(self, msg: Any) -> None:
        """Hand a supervised message of the autopilot (``SUPERVISED_MESSAGES``) to the supervisor; what it notes
        goes into the loop's events too."""
        sup = self.supervisor
        n = len(sup.notes)
        sup.observe(msg, self._now_vehicle())
        for note in sup.notes[n:]:
            self.events.append(LoopEvent(self.t_vehicle, time.monotonic(), note.kind, note.text))

    def _on_timesync(self, msg: Any, t_local: float) -> None:
        """A TIMESYNC answer to one of the loop's requests (``offboard.flight.latency``)."""
        lat = self.latency
        sent = lat._pending.get(msg.ts1)
        lat.on_timesync(msg.tc1, msg.ts1, self._now_vehicle() if self.cfg.lockstep else t_local)
        if sent is not None and not self.cfg.lockstep:  # keep the vehicle clock's offset fresh too
            self.conn.clock.observe_timesync(msg.tc1 * 1e-9, sent, t_local)

    def _measure_link(self, t_v: float) -> None:
        """Once per tick / keep-alive: the telemetry age, a TIMESYNC request when due, the latency watchdog."""
        lat = self.latency
        a = self.last_att
        # one age per attitude sample, taken at the first tick that sees it: a sample lost on the way leaves the
        # previous one in place, and its age at later ticks is the loss's gap, not the link's delay (at 30 % loss
        # the gaps read as 15-30 ms of "delay" and resized the filter for a fast link)
        if a is not None and a.t > self._aged_sample_t:
            self._aged_sample_t = a.t
            if self.cfg.lockstep:
                lat.on_telemetry_age(t_v - a.t)
            elif self.conn.clock.source == "timesync" and self.conn.clock.steady:
                # only while the clock's fitted rate holds (``VehicleClock.steady``): before it is fitted, or while
                # it changes, a vehicle clock running slow (PX4 SITL under load) reads as telemetry growing old,
                # and the latency watchdog fired during the approach and in flight (CI, 2026-12-02)
                lat.on_telemetry_age(self.conn.clock.to_vehicle(self._att_arrival) - a.t)
        now = self._now_vehicle() if self.cfg.lockstep else time.monotonic()
        if lat.due(now):
            self.stats.sent_bytes += len(self.conn.send(lat.request(self.conn.mav, now)))
        why = lat.check(now)
        if why is not None:
            raise FlightAbortError("latency", why)

    def _on_attitude_target(self, msg: Any) -> None:
        """The autopilot's ATTITUDE_TARGET: its thrust to the hover throttle's learning (in the air); during control
        compared with the setpoints sent (``setpoint_echo``); a large mismatch is left for the next tick's watchdogs
        to end the flight (not raised inside a read)."""
        learner = self.hover_learner
        if learner is not None:
            learner.on_thrust(msg.time_boot_ms * 1e-3, msg.thrust, self.last_att, self.last_pos)
            if learner.load_lost is not None and not learner.load_lost_told:
                learner.load_lost_told = True
                self.event("load_lost", learner.load_lost)
            while learner.line_events:  # line_slack / line_taut (offboard.flight.line_slack)
                self.event(*learner.line_events.pop(0))
        if not self._echo_on or msg.type_mask & ATTITUDE_IGNORE or not all(map(math.isfinite, msg.q)):
            return
        said = self.echo.target(msg.time_boot_ms * 1e-3, msg.q)
        if said is None:
            return
        what, text = said
        if what == "abort":
            self._foreign_verdict = self._foreign_verdict or text
        else:
            self.event("foreign_setpoint", text)

    def _dropped_counts(self) -> dict[str, int]:
        """The link's refusal counters (cumulative), by ``offboard.flight.dropped_data`` kind."""
        st = self.conn.stats
        sg = getattr(getattr(self.conn, "mav", None), "signing", None)
        signed = sg is not None and getattr(self.conn, "signing", None) is not None
        return {
            "nonfinite_telemetry": self.decoder.counts.get("refused_nonfinite", 0),
            "foreign_sender": getattr(st, "foreign_datagrams", 0),
            "refused_signature": sg.badsig_count + getattr(st, "refused_unsigned", 0) if signed else 0,
        }

    def _report_dropped(self, final: bool = False) -> None:
        """New refusals as events (each a warning line), rate-limited per kind; ``final``: all that is left."""
        d = self.dropped
        for kind, text in (d.flush if final else d.check)(time.monotonic(), self._dropped_counts()):
            self.event(kind, text)
        systems = getattr(self.conn.stats, "foreign_systems", {})
        if len(systems) > len(self._systems_told):  # a new system on the link: once per system
            for sys_id in sorted(set(systems) - self._systems_told):
                self._systems_told.add(sys_id)
                self.event(
                    "foreign_system",
                    f"MAVLink system {sys_id} is on the link too: its messages are not the autopilot's",
                )

    def _supervision_verdict(self) -> None:
        """Raise the supervisor's verdict, if it has one (once per tick and per approach step)."""
        v: Verdict | None = self.supervisor.check(self._now_vehicle())
        if v is not None:
            raise FlightAbortError(v.kind, v.reason, v.action)

    def _wait(self, timeout: float) -> bool:
        """Block up to ``timeout`` s for a trigger; True if one arrived. A signal cuts the wait short, except while
        the loop hands the vehicle over (``_finishing``: the exit stream stays paced)."""
        t_end = time.monotonic() + timeout
        while True:
            if self._read():
                return True
            left = t_end - time.monotonic()
            if left <= 0.0 or (self._signal is not None and not self._finishing):
                return False
            if self.conn.backlog:  # received already, past the read budget: handle it before blocking
                continue
            if self._fd is not None:
                select.select([self._fd], [], [], min(left, 0.05))
            else:
                time.sleep(min(left, 0.0005))

    def _on_global_position(self, msg: Any, t_local: float) -> None:
        """GLOBAL_POSITION_INT: the altitude (AMSL) and the autopilot's own height above home; paired with a fresh
        local position it tells where home is in the local frame."""
        self.alt_amsl = msg.alt * 1e-3
        self.rel_alt = msg.relative_alt * 1e-3
        self.home_alt = self.alt_amsl - self.rel_alt
        p = self.last_pos
        if p is not None and t_local - self.last_rx_local.get("PositionVelocity", -math.inf) < 0.05:
            self._home_z_samples.append(p.z - self.rel_alt)

    def _vehicle_now(self) -> float:
        """Current vehicle time (s) from the newest attitude sample and its arrival (real time)."""
        a = self.last_att
        if a is None:
            return self.conn.clock.to_vehicle(time.monotonic())
        return a.t + (time.monotonic() - self._att_arrival)

    def _now_vehicle(self) -> float:
        if self.cfg.lockstep:
            return self.marker_t if self.marker_t is not None else (self.last_att.t if self.last_att else 0.0)
        return time.monotonic()

    def _watchdogs(self, t_v: float, now: float) -> None:
        cfg = self.cfg
        if cfg.lockstep:
            ages = {
                k: t_v - m.t
                for k, m in (("Attitude", self.last_att), ("PositionVelocity", self.last_pos))
                if m is not None
            }
        else:
            ages = {k: now - self.last_rx_local.get(k, -math.inf) for k in ("Attitude", "PositionVelocity")}
        limit = self.staleness.limit_s
        for k, age in ages.items():
            if age > limit:
                raise FlightAbortError("telemetry_stale", f"no {k} telemetry for {age:.3f} s (limit {limit:.3g} s)")
        if self._foreign_verdict is not None:
            raise FlightAbortError("foreign_setpoint", self._foreign_verdict)
        self._supervision_verdict()
        self._measure_link(t_v)

    # ------------------------------------------------------------------------------------------ signals ---
    def _on_signal(self, signum: int, frame: Any) -> None:
        self._signal = signum

    def _install_signals(self) -> dict[int, Any]:
        old: dict[int, Any] = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread: the caller handles signals
                old[sig] = signal.signal(sig, self._on_signal)
        return old

    @staticmethod
    def _restore_signals(old: dict[int, Any]) -> None:
        for sig, h in old.items():
            signal.signal(sig, h)


def _fileno(conn: MavConnection) -> int | None:
    port = getattr(conn.conn, "port", None)
    try:
        return port.fileno() if port is not None else conn.conn.fd
    except Exception:
        return None
