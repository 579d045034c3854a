"""The real-time offboard loop: telemetry -> Kalman filter -> sliding-mode controller -> setpoint, at a fixed rate,
with watchdogs, signal handling and loop statistics. Single-threaded; the same estimator and controller code as
``slung sim`` (``estimators.filters.factory.make_estimator``, ``offboard.control.smc.step``).

Pacing
    ``realtime`` (default): the loop asks the autopilot for ATTITUDE at ``rate_hz`` and runs one tick as soon as
    each ATTITUDE arrives (so the telemetry-to-setpoint latency is the compute time, not up to a period); when
    no ATTITUDE arrives within 1.5 periods of the previous tick, the tick runs on that deadline instead. The
    vehicle time of a tick is the local time mapped through :class:`~offboard.flight.link.connection.VehicleClock`.
    ``lockstep`` (the bundled emulator's handshake, ``docs/emulator.md``): every setpoint advances the emulated
    vehicle by one period; it then sends the telemetry of that period and a SYSTEM_TIME marker whose
    ``time_boot_ms`` is the new simulation time. One tick per marker, at the marker's time. A marker that does not
    come within ``lockstep_wait_s`` (lost packet) is replaced by a tick at the predicted time; one that comes after
    that (a loaded machine) is not ticked again: the next marker is awaited (``FlightLoop._next_step``).
    Rate: default 250 Hz, accepted 20..1000 Hz (500 Hz is measured in ``bench/bench_loop.py``).

Each tick
    new measurements are pushed to the estimator as they are read; ``estimate(t)`` -> ``smc.step`` with the
    reference at ``t - t0`` (shifted horizontally so that it starts where the vehicle is when offboard control
    begins) -> :class:`~offboard.flight.command_mapping.CommandMapper` -> encoded, checked and sent; the command is fed
    back to the estimator (``push_command``) as the motors deliver it (:class:`ActuatorLag`).

Watchdogs (each ends offboard control by switching the vehicle to its hold mode, logged with the reason)
    - ``telemetry_stale``: no ATTITUDE or no position for ``stale_s`` (default 0.1 s; wall time in real time,
      vehicle time in lockstep);
    - ``estimator_divergence``: a non-finite estimate, or the estimated vehicle position more than
      ``divergence_m`` (default 1 m) from the autopilot's latest position;
    - ``swing_limit``: estimated swing ``hypot(alpha_x, alpha_y)`` above ``swing_limit_rad`` (default 0.8 rad);
    - ``loop_overrun``: one estimator update took longer than ``stale_s`` (an overloaded computer, or the filter
      catching up after a stall): the loop can no longer keep its deadlines. Real time only: in lockstep the
      vehicle waits for each setpoint, so no deadline exists and a slow machine must not end the flight;
    - supervision (``offboard/flight/supervisor.py``): an unrequested mode change or disarm (the vehicle is left to its
      new owner), an unconfirmed mode switch, a tracking error above ``tracking_limit_m``;
    - ``internal_error``: any exception in the flight: hold, report, exit 1 (one top-level guard in ``run``);
    - ``signal``: SIGINT / SIGTERM -> ``signal_action`` (hold or land).
    After a hold / land request the loop keeps streaming a hover setpoint until the heartbeat shows the new mode
    (or ``exit_timeout_s`` passes), so the vehicle is never left in offboard mode with a dead stream.

Statistics (:class:`LoopStats`): achieved rate, compute time (tick start to setpoint written) p50 / p99,
telemetry-to-setpoint latency (arrival of the newest telemetry used to setpoint written) p50 / p99, and missed
deadlines: ticks whose setpoint left more than 1.5 periods after the previous one, or whose compute time
exceeded a period.

Why this module is over 500 lines: it is one object, :class:`FlightLoop`, the live flight from preflight to the
end (start-up phases, the tick loop, watchdogs, the finish) over one shared state that every phase reads and
writes (the link, the estimator, the mapper, the clock, the statistics); cut into files, that state would be
passed around or reached through mixins. What stands alone is elsewhere: its configuration and records in
``offboard.flight.loop_records``, the approach's settling checks in ``offboard.flight.start_checks``, the tick in
``offboard.control.tick``, supervision in ``offboard.flight.supervisor``, the link in ``offboard.flight.link``.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import math
import select
import signal
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from estimators.filters.factory import Estimator
from estimators.model.cable import swing_amplitude
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_chain, flat_constants, world_tilt
from estimators.model.frames import model_euler_to_ned, model_to_ned_vector
from estimators.model.measurements import Attitude, LoadAngle, Measurement, PositionVelocity, ReportedAccuracy
from estimators.model.vehicle import Vehicle
from offboard.control import smc, smc_attitude
from offboard.control.controllers.protocol import Controller
from offboard.control.controllers.sliding_mode import law_for
from offboard.control.delay_margin import gain_scale, loop_delay
from offboard.control.tick import ActuatorLag, ControlTick
from offboard.flight.attitude_mapping import inner_loop_of
from offboard.flight.command_mapping import CommandMapper, setpoint_fields
from offboard.flight.latency import LinkLatency
from offboard.flight.link.autopilot_model import choose_hover_throttle
from offboard.flight.link.connection import MavConnection
from offboard.flight.link.management import Manager, custom_mode
from offboard.flight.link.setpoints import SetpointError, encode, encode_position
from offboard.flight.link.telemetry import TelemetryDecoder
from offboard.flight.loop_records import (
    DEFAULT_RATE_HZ,
    LIVE_COL,
    LIVE_COLUMNS,
    RATE_MAX_HZ,
    RATE_MIN_HZ,
    FlightResult,
    LoopConfig,
    LoopEvent,
    LoopStats,
    TruthProbe,
)
from offboard.flight.start_checks import offset_and_noise, settled, standard_error
from offboard.flight.supervisor import Supervisor, Verdict, mode_name

log = logging.getLogger(__name__)

#: lockstep: how much longer (wall s) a tick waits for the next step marker after a late one (``_next_step``)
LATE_MARKER_WAIT_S = 0.25

#: the autopilot's messages the supervisor reads (``offboard.flight.supervisor``)
_SUPERVISED = frozenset(("HEARTBEAT", "STATUSTEXT", "COMMAND_ACK"))


class _AbortError(Exception):
    def __init__(self, kind: str, reason: str, action: str = "hold") -> None:
        super().__init__(reason)
        self.kind, self.reason, self.action = kind, reason, action


class FlightLoop:
    """One flight: pre-flight, take-off, offboard control of ``reference`` for ``duration`` s, end.

    conn: an open :class:`MavConnection` (heartbeat already received); vehicle: the controller's nominal
    vehicle; params: controller parameters; mapper: setpoint mapping; estimator: a fresh estimator (``kf``);
    truth_probe: optional (the demo's emulator runs in-process and tells the true plant state, for metrics only:
    nothing of it reaches the estimator or controller); on_reference_start: optional, called once with the vehicle
    time (s) at which the reference's t = 0 is, before the first command of the flight (the demo starts the
    emulator's disturbance clock there).
    """

    def __init__(
        self,
        conn: MavConnection,
        vehicle: Vehicle,
        reference: Any,
        duration: float,
        params: smc.ControllerParams | smc_attitude.AttitudeParams,
        mapper: CommandMapper,
        estimator: Estimator,
        config: LoopConfig,
        truth_probe: TruthProbe | None = None,
        manager: Manager | None = None,
        estimator_factory: Callable[..., Estimator] | None = None,
        on_reference_start: Callable[[float], None] | None = None,
        controller: Controller | None = None,
        torque_fallback: smc.ControllerParams | None = None,
    ) -> None:
        config.validate()
        self.conn = conn
        self.vehicle = vehicle
        self.reference = reference
        self.duration = duration
        self.params = params
        #: the control law (default: the sliding-mode law of ``params``, torque or attitude level, built again at
        #: the start of control: the attitude-level law's gains follow the autopilot's loops read in flight)
        self._controller_given = controller
        self.controller: Controller = controller if controller is not None else law_for(params)
        self.mapper = mapper
        #: ``--law auto``: the torque-level law to fly if the attitude-level law has no robust gains behind the
        #: autopilot's own attitude loop (read before the take-off); ``flew_torque_fallback`` says it was taken
        self._torque_fallback = torque_fallback
        self.flew_torque_fallback = False
        self.estimator = estimator
        self.cfg = config
        self.truth_probe = truth_probe
        self.on_reference_start = on_reference_start
        self.estimator_factory = estimator_factory
        self._guess: ControlState | None = None
        self._att_arrival = 0.0
        self.mgr = manager or Manager(conn)
        assert conn.vehicle is not None, "wait_heartbeat() first"
        self.target = (conn.vehicle.system, conn.vehicle.component)
        self.decoder = TelemetryDecoder(system=conn.vehicle.system)
        mav = getattr(conn, "mav", None)
        own = (getattr(mav, "srcSystem", 255), getattr(mav, "srcComponent", 191))
        self.supervisor = Supervisor(
            conn.vehicle.flavour, own, config.tracking_limit_m, own_systems=getattr(conn, "own_systems", ())
        )
        self.latency = LinkLatency(config.lockstep, config.latency_limit_s)
        #: the filter's fusion horizon (s); grows at the start of control when the link is slow (_size_for_link)
        self.filter_delay_s = config.base_filter_delay_s
        #: the largest horizon the filter can predict over (s): 0 until _size_for_link
        self.horizon_budget_s = 0.0
        #: the torque-level law's pole scale for the measured loop delay (_schedule_gains)
        self.gain_scale = 1.0
        self.events: list[LoopEvent] = []
        self.rows: list[tuple[float, ...]] = []
        self.stats = LoopStats()
        self.period = 1.0 / config.rate_hz
        self.k = flat_constants(vehicle)
        # latest telemetry
        self.last_att: Attitude | None = None
        self.last_pos: PositionVelocity | None = None
        self.last_load: LoadAngle | None = None
        self.last_rx_local: dict[str, float] = {}
        #: AMSL altitude of the vehicle (m, GLOBAL_POSITION_INT.alt) and its height above home as the autopilot
        #: reports it (m, relative_alt), latest
        self.alt_amsl: float | None = None
        self.rel_alt: float | None = None
        self.home_alt: float | None = None
        #: samples of the take-off point's local z as the autopilot reports it (local z - relative_alt, model
        #: frame, m), and recent local z samples (m) for the vehicle on the ground
        self._home_z_samples: deque[float] = deque(maxlen=50)
        self._z_samples: deque[float] = deque(maxlen=100)
        #: local z (model frame, m) of the take-off point: heights in the references are above it (None: not fixed
        #: yet, heights are local z). PX4's local origin is where EKF2 started, not the ground.
        self.ground_z: float | None = None
        self.n_meas = 0
        self.pending: list[Measurement] = []
        self.estimator_ready = False
        self.marker_t: float | None = None
        self.marker_local = 0.0
        self.trigger_local: float | None = None
        self.last_send_local: float | None = None
        self.last_sp: Any = None
        self.t_vehicle = 0.0
        self._signal: int | None = None
        #: position + heading (model frame) held with position setpoints before the controller takes over
        self.goal: tuple[float, float, float, float] | None = None
        self._fd = _fileno(conn)
        self._inject = config.inject_nan
        self._t0_meas = math.inf
        self._triggered = False
        conn.listener = self._on_received

    # ------------------------------------------------------------------------------------------ helpers ---
    def event(self, kind: str, reason: str) -> None:
        """Record an event (and log it)."""
        self.events.append(LoopEvent(self.t_vehicle, time.monotonic(), kind, reason))
        routine = kind == "phase" or (kind.startswith("exit") and self._ending_normally)
        log.info("%s: %s", kind, reason) if routine else log.warning("%s: %s", kind, reason)

    def _injected(self, stage: str, t_ref: float) -> bool:
        return any(s == stage and a <= t_ref <= b for s, a, b in self._inject)

    def _tamper(self, stage: str, t_ref: float, value: Any) -> Any:
        """The tick's fault hook (``LoopConfig.inject_nan``): a NaN estimate, a NaN reference, a NaN / inf command."""
        if not self._injected(stage, t_ref):
            return value
        if stage == "estimate":
            return value._replace(theta=math.nan)
        if stage == "reference":
            return (math.nan, *value[1:])
        return value._replace(tau_phi=math.inf, thrust=math.nan)

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
            if kind in _SUPERVISED:
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
            if kind == "GLOBAL_POSITION_INT":
                self._on_global_position(msg, r.t_local)
                continue
            m = self.decoder.decode(msg)
            if m is None:
                continue
            if self._inject and isinstance(m, Attitude) and self._injected("measurement", m.t - self._t0_meas):
                m = m._replace(phi=math.nan)
            self.last_rx_local[type(m).__name__] = r.t_local
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
            if self.estimator_ready:
                self.estimator.push(m)
                self.n_meas += 1

    def _supervise(self, msg: Any) -> None:
        """Hand a HEARTBEAT / STATUSTEXT / COMMAND_ACK of the autopilot to the supervisor; what it notes goes into
        the loop's events too."""
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
            raise _AbortError("latency", why)

    def _size_for_link(self) -> None:
        """At the start of control: if the measured delays need it, rebuild the (not yet initialized) filter with a
        fusion horizon that covers them (``offboard.flight.latency``), and allow the controller's prediction up to that
        room. The telemetry age includes the sensors' own latency, which the base horizon already covers: while the
        largest age plus the largest setpoint way stays within the base horizon nothing changes."""
        lat = self.latency
        need = (max(lat.ages) if lat.ages else 0.0) + (max(lat.ways) if lat.ways else 0.0)
        base = self.cfg.base_filter_delay_s
        if need <= base or self.estimator_factory is None:
            return
        budget = min(1.25 * need, 2.0 * self.cfg.latency_limit_s)
        delay = base + budget
        try:
            est = self.estimator_factory(delay_s=delay)
        except TypeError:  # a harness's factory without the delay: no prediction over the link
            return
        self.estimator, self.filter_delay_s, self.horizon_budget_s = est, delay, budget
        lat.max_horizon_s = budget
        self.event(
            "phase",
            f"link delays: telemetry {lat.age_s * 1e3:.1f} ms, setpoints {lat.way_s * 1e3:.1f} ms: the filter "
            f"fuses {delay * 1e3:.0f} ms behind and the controller predicts up to {budget * 1e3:.0f} ms ahead",
        )

    def _schedule_gains(self) -> None:
        """At the start of control: the torque-level law's poles scaled so that its loops keep, at the measured
        loop delay (motors + telemetry age + setpoint way, medians), the phase margin the paper's gains have on a
        direct link (``offboard.control.delay_margin``, docs/model.md §11). A law given by the caller is left alone; the
        attitude-level law's gains are designed for 0-30 ms of delay already (§12.3)."""
        params = self.params
        if self._controller_given is not None or not isinstance(params, smc.ControllerParams):
            return
        lat = self.latency
        tau_m = self.vehicle.motor_time_constant
        tau = loop_delay(tau_m, lat.age_s, lat.way_s)
        f = gain_scale(tau_m, tau, self.cfg.base_filter_delay_s)
        if f >= 1.0:
            return
        self.gain_scale = f
        self.params = replace(params, gains=params.gains.scaled(f))
        self.event(
            "phase",
            f"loop delay {tau * 1e3:.0f} ms (motors {tau_m * 1e3:.0f}, telemetry {lat.age_s * 1e3:.0f}, setpoints "
            f"{lat.way_s * 1e3:.0f}): the torque-level law's poles scaled by {f:.3f} to keep its delay margin",
        )

    def _supervision_verdict(self) -> None:
        """Raise the supervisor's verdict, if it has one (once per tick and per approach step)."""
        v: Verdict | None = self.supervisor.check(self._now_vehicle())
        if v is not None:
            raise _AbortError(v.kind, v.reason, v.action)

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

    def fix_ground(self) -> None:
        """Fix :attr:`ground_z`, the take-off point's local z, once, before the take-off decision.

        On the ground (the autopilot's height above home under 0.3 m, or unknown) with a take-off to fly: the mean
        of the last position samples, where the vehicle sits. In the air (``--no-takeoff``, or a vehicle already
        flying): home as the autopilot reports it, the median of ``local z - relative_alt``. Without
        GLOBAL_POSITION_INT in the air: local z itself, with a warning."""
        if self.ground_z is not None:
            return
        airborne = self.rel_alt is not None and self.rel_alt > 0.3
        if self.cfg.takeoff and not airborne and self._z_samples:
            zs = list(self._z_samples)
            mean = sum(zs) / len(zs)
            if abs(mean) <= 3.0 * standard_error(zs):
                # the local origin is on the ground as far as the samples can tell (an emulator's is exactly):
                # keep heights as they are rather than shift them by the estimate's noise
                self.ground_z = 0.0
                how = f"the local origin (the mean of {len(zs)} position samples, {mean:+.4f} m, is within its noise)"
            else:
                self.ground_z = mean
                how = f"the mean of {len(zs)} position samples on the ground"
        elif self._home_z_samples:
            self.ground_z = float(np.median(np.asarray(self._home_z_samples)))
            how = f"home as the autopilot reports it ({len(self._home_z_samples)} GLOBAL_POSITION_INT samples)"
        else:
            self.ground_z = 0.0
            how = "unknown (no GLOBAL_POSITION_INT): heights are the autopilot's local z"
            self.mgr.warnings.append("take-off point unknown: reference heights are taken as local z")
        self.event("phase", f"take-off point at local z {self.ground_z:+.3f} m (model frame, up): {how}")

    def height(self) -> float | None:
        """Latest height above the take-off point from telemetry (m), None if none yet."""
        if self.last_pos is None:
            return None
        return self.last_pos.z - (self.ground_z or 0.0)

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

    def _abort_on_signal(self) -> None:
        """Raise the signal abort now if Ctrl-C / SIGTERM arrived: the management phases (stream requests, arming,
        the autopilot's take-off, the mode switch) wait in loops that call the idle callbacks below, and a signal
        must end them at once (hold or land from where the vehicle is), not after the take-off has finished."""
        if self._signal is not None:
            raise _AbortError("signal", f"signal {self._signal} before the flight", self.cfg.signal_action)

    def stream_hover(self) -> None:
        """Send one keep-alive setpoint (the position goal before control starts, else a hover attitude) and pace
        to the loop rate (management's idle callback while streaming)."""
        self._abort_on_signal()
        if self.supervisor.active:
            self._supervision_verdict()
            self._measure_link(self._now_vehicle() if self.cfg.lockstep else self._vehicle_now())
        if self.goal is not None:
            self._send_goal()
        else:
            self._send(self._hover_sp(), self.t_vehicle)
        if self.cfg.lockstep:
            self._wait(self.cfg.lockstep_wait_s)
        else:
            t_end = time.monotonic() + self.period
            while time.monotonic() < t_end:
                self._read()
                time.sleep(min(0.0005, max(0.0, t_end - time.monotonic())))

    def _idle_read(self) -> None:
        self._abort_on_signal()
        self._read()

    def _prime(self, seconds: float) -> None:
        """Stream hover setpoints for ``seconds`` of vehicle time (PX4 needs the stream before the switch; ArduPilot,
        0 s, does not, and nothing is said)."""
        if seconds <= 0.0:
            return
        start = self._now_vehicle()
        n = 0
        while self._now_vehicle() - start < seconds:
            self.stream_hover()
            n += 1
            if self._signal is not None:
                raise _AbortError("signal", f"signal {self._signal} while priming", self.cfg.signal_action)
        self.event("phase", f"primed the setpoint stream: {n} setpoints over {seconds:g} s")

    def _approach(self, settle_s: float = 0.5, timeout_s: float | None = None, noise_s: float = 3.0) -> None:
        """Hold the position goal (the reference's start) until, averaged over the last ``settle_s`` of vehicle
        time, the vehicle is at it, at rest and its swing small, each within what the telemetry's own scatter
        lets one tell (:func:`settled`: two standard errors of the mean, estimated over the last ``noise_s``, at
        least 1 cm, 3 cm/s, 0.02 rad);
        at most ``timeout_s`` (default ``start_timeout_s``), then control starts anyway and the event says how far
        off the vehicle was and how noisy its position.

        The averages make the criterion noise-aware: single samples of a real (or emulated ``px4-typical``)
        estimate scatter by 2-3 cm and 3 cm/s, above the floors, while the mean of the ~50 position and
        ~125 load-angle samples of 0.5 s scatters by a few millimetres; a real autopilot's estimate wanders by
        decimetres (PX4 SITL: GPS noise), and samples that wander together carry less information than white ones,
        which the standard error's effective sample count accounts for."""
        assert self.goal is not None
        gx, gy, gz, _ = self.goal
        if timeout_s is None:
            timeout_s = self.cfg.start_timeout_s
        start = self._now_vehicle()
        # window entries are stamped with the loop's clock (``_now_vehicle``: vehicle time in lockstep, local time
        # in real time); a new sample is one with a newer sample time
        pos: deque[tuple[float, float, float, float, float, float, float]] = deque()
        noise: deque[tuple[float, float, float, float, float, float, float]] = deque()
        swing: deque[tuple[float, float, float]] = deque()
        last_p = last_l = -math.inf
        while True:
            self.stream_hover()
            now = self._now_vehicle()
            p, ld = self.last_pos, self.last_load
            fresh = False
            if p is not None and p.t > last_p:
                last_p = p.t
                pos.append((now, p.x, p.y, p.z, p.vx, p.vy, p.vz))
                noise.append(pos[-1])
                fresh = True
            if ld is not None and ld.t > last_l:
                last_l = ld.t
                swing.append((now, ld.alpha_x, ld.alpha_y))
            for q, span in ((pos, settle_s), (swing, settle_s), (noise, noise_s)):
                while q and q[0][0] < now - span:
                    q.popleft()
            if fresh and settled(pos, swing, gx, gy, gz, now - start >= settle_s, ld is not None, noise):
                self.event("phase", f"at the start of the reference after {now - start:.2f} s")
                return
            if now - start > timeout_s:
                off, scatter = offset_and_noise(noise, gx, gy, gz)
                self.event(
                    "phase",
                    f"start of the reference not reached within {timeout_s:g} s: starting anyway, {off:.2f} m from "
                    f"it on average over the last {noise_s:g} s (position scatter {scatter:.2f} m)",
                )
                return
            if self._signal is not None:
                raise _AbortError("signal", f"signal {self._signal} before the flight", self.cfg.signal_action)

    def _reread_hover_throttle(self) -> None:
        """After the take-off and the hold at the start, read the hover throttle again (ArduPilot learns
        MOT_THST_HOVER in flight, with the load on) and map thrust with it from now on."""
        h = choose_hover_throttle(self.mgr.flavour, self.mgr.read_hover_throttle(), self.vehicle)[0]
        before = self.mapper.autopilot.hover_thrust_norm
        if h is None or h == before:
            return
        self.mapper.set_autopilot(replace(self.mapper.autopilot, hover_thrust_norm=h))
        self.event("phase", f"hover throttle re-read in flight: {h:.3f} (before the take-off: {before})")

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

    # ------------------------------------------------------------------------------------------ phases ---
    def preflight(self) -> None:
        """Streams, telemetry present and fresh, autopilot model, thrust semantics (ArduPilot)."""
        from estimators.errors import UserError

        rate = self.cfg.rate_hz
        streams = {
            "ATTITUDE": rate,
            "LOCAL_POSITION_NED": min(rate, 100.0),
            "HIGHRES_IMU": rate,
            "DEBUG_VECT": min(rate, 250.0),
        }
        self.mgr.request_streams(streams, idle=self._idle_read)
        self.conn.request_timesync(time.monotonic())
        wait_s = self.cfg.telemetry_timeout_s
        self.event("phase", f"waiting up to {wait_s:g} s for ATTITUDE and LOCAL_POSITION_NED telemetry")
        ok = self.mgr.wait_for(
            lambda: (self._read() or True) and self.last_att is not None and self.last_pos is not None,
            wait_s,
        )
        if not ok:
            wanted = (("attitude (ATTITUDE)", self.last_att), ("position (LOCAL_POSITION_NED)", self.last_pos))
            missing = [name for name, m in wanted if m is None]
            got = ", ".join(sorted(self.last_rx_local)) or "nothing decoded"
            raise UserError(
                f"no {' and no '.join(missing)} telemetry within {wait_s:g} s (got: {got}); an autopilot that "
                "streams its local position only once its estimator has converged needs a longer "
                "--telemetry-timeout"
            )
        # give the load-angle sensor a moment to show up
        self.mgr.wait_for(lambda: (self._read() or True) and self.last_load is not None, 0.5)
        self.mgr.check_vehicle_constants(self.vehicle)
        self.initialize_estimator(warm_up=True)
        # the full garbage collection the flight will not run (see _fly), now, before any setpoint is streamed
        gc.collect()
        self.event("phase", "preflight ok: " + ", ".join(f"{k}" for k in sorted(self.last_rx_local)))

    def initialize_estimator(self, warm_up: bool = False) -> None:
        """Initialize the filter from the latest telemetry (vehicle at rest, swing from the sensor or 0);
        ``warm_up``: only to warm a copy up (before take-off, while nothing has to be streamed)."""
        a, p = self.last_att, self.last_pos
        assert a is not None and p is not None
        guess = initial_guess(self.vehicle, a, p, self.last_load)
        t0 = max(a.t, p.t)
        self._guess = guess
        if warm_up:
            self._warm_up(t0)
            return
        self.estimator.initialize(t0, guess)
        self.estimator_ready = True
        self.t_vehicle = t0

    def _warm_up(self, t0: float, max_step_ms: int = 100) -> None:
        """Run a scratch filter (``estimator_factory``) through steps of 1..``max_step_ms`` ms (the lengths a
        real-time loop on the 1 ms vehicle clock produces), so that its per-step-length discretizations are
        computed before the flight, not in the first ticks (where each new length costs milliseconds and a slow
        tick makes longer, new steps: a spiral). The scratch filter is discarded."""
        if self.estimator_factory is None:
            return
        scratch = self.estimator_factory()  # a new instance shares the filter's class-level discretization cache
        a, p = self.last_att, self.last_pos
        assert a is not None and p is not None
        scratch.initialize(t0, self._guess)
        hover = self.vehicle.hover_thrust
        t = t0
        for h in range(1, max_step_ms + 1):
            t += h * 1e-3
            for lag in (0.001, 0.002, 0.003):
                scratch.push(a._replace(t=t - lag))
                scratch.push(p._replace(t=t - lag))
                if self.last_load is not None:
                    scratch.push(self.last_load._replace(t=t - lag))
            scratch.push_command(t, hover, (0.0, 0.0, 0.0))
            scratch.estimate(t)

    def _fly_torque_fallback(self, inner: smc_attitude.InnerLoop) -> None:
        """``--law auto`` took the attitude-level law on PX4's default attitude loop, but this autopilot's loop
        leaves it no gains robust to that loop off by 2x (docs/model.md §12.5): fly the torque-level law through
        the same attitude output instead (its mapping inverts the autopilot's cascade), before any command."""
        assert self._torque_fallback is not None
        self.params = self._torque_fallback
        self.mapper = CommandMapper(self.vehicle, self.mapper.config, self.mapper.autopilot)
        self.flew_torque_fallback = True  # the law itself is built from self.params at the start of control
        self.event(
            "phase",
            f"--law auto: the torque-level law: this autopilot's attitude loop ({inner.attitude_bandwidth:g} 1/s) "
            f"leaves the attitude-level law no robust gains for this load's swing "
            f"({self.vehicle.pendulum_frequency:.1f} rad/s)",
        )

    # ---------------------------------------------------------------------------------------- the flight ---
    def run(self) -> FlightResult:
        """Fly: pre-flight, take-off, prime, offboard control, end (hold / land). Signal handlers are installed
        for the duration of the call (main thread only)."""
        old = self._install_signals()
        ended_by, end_state = "completed", ""
        origin = (0.0, 0.0)
        try:
            self.preflight()
            ref0 = self.reference.sample(0.0)
            if self.mgr.flavour == "ardupilot":
                self.mgr.ensure_ardupilot_thrust_mode()
            self.mapper.set_autopilot(self.mgr.read_autopilot_model(self.vehicle))
            tilt = self.mgr.read_tilt_limit()
            if tilt is not None:
                self.mapper.limit_tilt(tilt)
                self.event(
                    "phase",
                    f"autopilot tilt limit {math.degrees(tilt):.1f} deg: setpoints within "
                    f"{math.degrees(self.mapper.config.max_tilt):.1f} deg",
                )
            if isinstance(self.params, smc_attitude.AttitudeParams):  # its gains depend on the autopilot's loops
                inner = inner_loop_of(self.mapper.autopilot)
                tilt_max = min(self.params.tilt_max, self.mapper.config.max_tilt)  # within the autopilot's limit
                self.params = self.params.with_inner(inner, tilt_max=tilt_max)
                robust = smc_attitude.robust_gains_exist(self.vehicle, inner, self.params.tilt_max)
                if not robust and self._torque_fallback is not None and self._controller_given is None:
                    self._fly_torque_fallback(inner)
                elif not robust:
                    self.mgr.warnings.append(
                        f"attitude-level law: no gains stay stable with this autopilot's attitude loop "
                        f"({inner.attitude_bandwidth:g} 1/s) off by 2x for this load's swing "
                        f"({self.vehicle.pendulum_frequency:.1f} rad/s); flying the slowest ones (--law torque?)"
                    )
            self.fix_ground()
            if self.cfg.takeoff:
                h0 = self.height() or 0.0
                if h0 < ref0.z[0] - 0.3:
                    prime = self.stream_hover if self.mgr.flavour == "px4" else self._idle_read
                    # PX4's take-off altitude is AMSL: the take-off point's own altitude (the vehicle is on it)
                    amsl0 = self.alt_amsl if self.alt_amsl is not None and h0 < 0.3 else self.home_alt
                    self.mgr.takeoff(ref0.z[0], amsl0, self.height, idle=prime)
            assert self.last_pos is not None
            oz = self.ground_z or 0.0
            origin = (self.last_pos.x - ref0.fx[0], self.last_pos.y - ref0.fy[0])
            self.goal = (self.last_pos.x, self.last_pos.y, ref0.z[0] + oz, ref0.psi[0])
            self._prime(self.cfg.prime_s if self.mgr.flavour == "px4" else 0.0)
            if not self.mgr.set_mode("offboard", idle=self.stream_hover):
                from estimators.errors import UserError

                res = self.mgr.last_mode_result
                said = "; ".join(self.conn.statustexts[-3:])
                if res is None:
                    raise UserError(
                        f"the autopilot never acknowledged the switch to offboard control (it said: {said})"
                    )
                raise UserError(f"the autopilot refused offboard control (result {res}): {said}")
            self.supervisor.expect(custom_mode(self.mgr.flavour, "offboard"), self._now_vehicle())
            self._approach()
            self._reread_hover_throttle()
            self.goal = None
            self._size_for_link()
            self._schedule_gains()
            self.initialize_estimator()
            if self._signal is not None:
                raise _AbortError("signal", f"signal {self._signal} during start-up", self.cfg.signal_action)
            self.event("phase", "offboard control started")
            self._fly(origin)
            self._ending_normally = True  # the exit is routine, not a warning
            end_state = self._finish(self.cfg.end_action, "end of the reference")
        except _AbortError as ab:
            ended_by = ab.kind
            self.event(ab.kind, ab.reason)
            end_state = self._finish_guarded(self._abort_action(ab), ab.reason)
        except Exception as exc:  # the one top-level guard: any fault ends in the hand-over
            from estimators.errors import UserError

            # armed: as the heartbeat says, or as our arm command's acknowledgement said (the heartbeat, at 1 Hz,
            # can be a second behind: a take-off refused right after arming found the vehicle "disarmed" and left
            # it armed on the ground)
            armed = (self.conn.vehicle is not None and self.conn.vehicle.armed) or self.mgr.armed_here
            if isinstance(exc, UserError) and not (armed and self.supervisor.active):
                if armed:  # refused after arming (take-off, offboard): make sure the vehicle holds
                    self._finish_guarded("hold", str(exc))
                    self._disarm_if_on_the_ground()
                raise
            ended_by = "internal_error"
            reason = f"{type(exc).__name__}: {exc}"
            log.exception("internal error in the flight loop")
            self.event("internal_error", reason)
            end_state = self._finish_guarded("hold", reason)
        finally:
            self._restore_signals(old)
        return FlightResult(
            self.rows,
            self.events,
            self.stats,
            ended_by,
            end_state,
            origin,
            dict(self.estimator.stats()) if self.estimator_ready else {},
            self.mapper.events,
            self.mgr.events,
            self.mgr.warnings,
            _autopilot_dict(self.mapper),
            self.last_load is not None,
            dict(self.decoder.counts),
            ground_z=self.ground_z or 0.0,
            supervision=self.supervisor.summary(),
            latency=self.latency.summary(),
            filter_delay_s=self.filter_delay_s,
            gain_scale=self.gain_scale,
            reference_duration_s=self.duration,
        )

    def _fly(self, origin: tuple[float, float]) -> None:
        cfg = self.cfg
        lockstep = cfg.lockstep
        t0 = self.t_vehicle
        if lockstep:  # one hover setpoint to get the emulator's current time
            self._send(self._hover_sp(), self.t_vehicle)
            self._wait(cfg.lockstep_wait_s)
            if self.marker_t is not None:
                t0 = self.marker_t
        else:
            t0 = round(self._vehicle_now(), 3)
        self._t0_meas = t_first = t0
        if self.horizon_budget_s > 0.0:  # the reference starts when the first setpoint acts
            t0 += min(self.latency.horizon(), self.horizon_budget_s)
        if self.on_reference_start is not None:  # before the first command: the harness starts its clocks at t0
            self.on_reference_start(t0)
        if self._controller_given is None:
            self.controller = law_for(self.params)
        self.controller.reset()
        wall0 = time.monotonic()
        last_marker = self.marker_t
        stats = self.stats
        t_v = t_first  # the observation clock starts at the vehicle's time (the action clock t0 is ahead of it)
        # no cyclic garbage collection during the flight: a full collection over the growing log costs
        # milliseconds, a missed deadline; the loop's objects are acyclic and freed by reference counting.
        # No collection here either: in a large process (a test session, a host application) it stalls for
        # 0.1 s or more between the last telemetry read and the first tick, and the stale-telemetry watchdog
        # ends the flight before it starts; preflight collects, where nothing is streamed yet. Freezing is O(1).
        gc.freeze()
        gc_was_enabled = gc.isenabled()
        gc.disable()
        try:
            self._fly_ticks(t0, t_v, last_marker, origin, wall0)
        finally:
            stats.elapsed_s = time.monotonic() - wall0
            if gc_was_enabled:
                gc.enable()
            gc.unfreeze()

    def _fly_ticks(
        self,
        t0: float,
        t_v: float,
        last_marker: float | None,
        origin: tuple[float, float],
        wall0: float,
    ) -> None:
        cfg = self.cfg
        period = self.period
        lockstep = cfg.lockstep
        oz = self.ground_z or 0.0  # heights of the reference are above the take-off point
        mapper = self.mapper
        controller = self.controller
        probe = self.truth_probe
        estimator = self.estimator
        nan9 = (math.nan,) * 9
        tick = ControlTick(
            controller,
            self.reference,
            estimator=self.estimator,
            mapper=mapper,
            lag=ActuatorLag(self.vehicle.motor_time_constant),
            origin=(origin[0], origin[1], oz),
            faults=self._tamper if self._inject else None,
            predict=estimate_ahead,
        )
        nan23 = (math.nan,) * 23
        nan4 = (math.nan,) * 4
        stats = self.stats
        link_lat = self.latency
        budget = self.horizon_budget_s
        settle_s = cfg.settle_s + float(getattr(self.reference, "stop_s", 0.0))  # the stop, then the settle
        last_est: ControlState | None = None
        # between ticks the filter fuses what the next tick's estimate would (MeasuredKalmanEstimator.prefuse), off
        # the path from telemetry to setpoint; slung replay does the same at the same place
        prefuse = getattr(estimator, "prefuse", None)
        prefuse_ahead = prefuse_lead(period)
        t_act = t_obs = t_v
        while True:
            t_v = t_obs  # the observation clock of the previous tick (t_v becomes the action time below)
            # ---- wait for the tick's trigger -------------------------------------------------------------
            if lockstep:
                t_next, last_marker = self._next_step(t_v, last_marker)
                if t_next is None:
                    t_v = t_v + period
                    stats.deadline_ticks += 1
                    self.trigger_local = None
                else:
                    t_v = t_next
            else:
                limit = 1.5 * period - (time.monotonic() - (self.last_send_local or time.monotonic()))
                got = self._wait(max(limit, 0.0))
                if not got:
                    stats.deadline_ticks += 1
                    self.trigger_local = None
                # vehicle time of the tick: the newest ATTITUDE's sample time plus the local time since it arrived
                # (robust to a drifting or slipping vehicle clock; behind the truth by the one-way link latency),
                # on the 1 ms grid of time_boot_ms so that the filter sees a small set of step lengths
                t_v = max(round(self._vehicle_now(), 3), t_v)
            # act on the state at the time this tick's setpoint will act (offboard.flight.latency): the tick's time plus
            # the measured horizon (0 on a fast link), never going backwards
            t_obs = t_v
            if budget > 0.0:
                t_act = max(t_v + min(link_lat.horizon(), budget), t_act)
                t_v = t_act
            # the demo's truth (metrics only), before this tick's setpoint lets a lockstep plant move on
            truth = probe(t_obs) if probe is not None and t_v - t0 <= self.duration + settle_s + 1e-9 else None
            tick_start = time.monotonic()
            perf0 = time.perf_counter()
            self.t_vehicle = t_v
            t_ref = t_v - t0
            if self._signal is not None:
                raise _AbortError("signal", f"signal {self._signal} received", cfg.signal_action)
            if t_ref > self.duration + 1e-9 and self._settled(last_est, t_ref - self.duration):
                break
            self._watchdogs(t_obs, tick_start)
            # ---- estimate (at the action time), reference, control, map, feed the filter (offboard.control.tick) ---
            nfb = mapper.fallbacks
            out = tick(t_v, t_ref)
            te = out.estimate_s
            stats.estimator.append(te)
            if te > cfg.stale_s and not lockstep:  # in lockstep the vehicle waits for the setpoint: no deadline
                raise _AbortError("loop_overrun", f"one filter update took {te:.3f} s (limit {cfg.stale_s:g} s)")
            est, ref, rfx, rfy, rz, cmd, sp = out.est, out.ref, out.rfx, out.rfy, out.rz, out.cmd, out.setpoint
            if self._inject and self._injected("setpoint", t_ref):
                sp = sp._replace(thrust=math.nan)
            buf = self._send(sp, t_ref, log=False)
            sent = time.monotonic()
            compute = time.perf_counter() - perf0
            # the setpoint is on the wire: now its tlog record (a slow write must not delay the setpoint)
            self.conn.log_sent(buf, time.time())
            sp = self.last_sp  # what left (the hover setpoint if the encoder refused this one): what the log records
            # ---- statistics and log ----------------------------------------------------------------------
            latency = math.nan
            if self.trigger_local is not None:
                latency = sent - self.trigger_local
                stats.latency.append(latency)
                self.trigger_local = None
            stats.compute.append(compute)
            if stats.ticks > 0 and self._prev_sent is not None:
                gap = sent - self._prev_sent
                stats.gaps.append(gap)
                if not lockstep and (gap > 1.5 * period or compute > period):
                    stats.missed += 1
            self._prev_sent = sent
            stats.ticks += 1
            tr = (*truth[0], truth[1], *(truth[2] if len(truth) > 2 else nan4)) if truth is not None else nan23
            spf = setpoint_fields(sp)
            self.rows.append(
                (
                    t_v,
                    t_ref,
                    tick_start,
                    float(self.n_meas),
                    *est[0],
                    *est[1],
                    *est[2:],
                    *estimator.sigmas(),  # reads that leave the filter as it was (the replay stays bit-identical)
                    *estimator.innovations(),
                    *rfx,
                    *rfy,
                    *rz[:3],
                    *ref.psi[:3],
                    *controller.memory_fields(),
                    *cmd[:8],
                    float(cmd.saturated),
                    float(cmd.valid),
                    *(spf + nan9[len(spf) :]),
                    float(mapper.fallbacks != nfb),
                    compute,
                    latency,
                    *tr,
                )
            )
            if prefuse is not None:  # the setpoint has left: what the next estimate would fuse first, now
                prefuse(t_v + prefuse_ahead)
            self._check_swing(est)
            last_est = est
            v = self.supervisor.check_tracking(est.fx[0] - rfx[0], est.fy[0] - rfy[0], est.z - rz[0])
            if v is not None:
                raise _AbortError(v.kind, v.reason, v.action)

    _prev_sent: float | None = None
    #: sample time (s, vehicle) of the newest attitude whose telemetry age was recorded (``_measure_link``)
    _aged_sample_t = -math.inf
    _ending_normally = False
    _finishing = False

    def _next_step(self, t_prev: float, last_marker: float | None) -> tuple[float | None, float | None]:
        """Lockstep: the vehicle time of the next tick (s), from the step markers, or None when none came within
        ``lockstep_wait_s`` (a lost marker or setpoint: the tick runs on the predicted time); and the newest marker.

        A marker no newer than the previous tick (``t_prev``) came late: the loop had already ticked for that step
        on the predicted time, and the setpoint it sent is moving the vehicle on to the next. Ticking again for it
        (what the loop did) put the loop one step behind the vehicle for good, one more step per late marker: under
        load (markers later than ``lockstep_wait_s`` of wall time) the 30 % loss hover lagged and lost its height
        (0.39 m beside ``stress --cpu 2``). So the next marker is awaited, up to ``LATE_MARKER_WAIT_S`` more (the
        vehicle waits for us in lockstep: no deadline is missed); only if none comes (that setpoint was lost and
        the vehicle still stands at the late marker's time) is the late marker's time ticked again."""
        deadline = time.monotonic() + self.cfg.lockstep_wait_s
        late: float | None = None
        while True:
            left = deadline - time.monotonic()
            if left <= 0.0 or not self._wait(left):
                return late, last_marker
            m = self.marker_t
            if m is None or m == last_marker:
                continue
            last_marker = m
            if m > t_prev + 1e-9:
                return m, last_marker
            late = m
            deadline = max(deadline, time.monotonic() + LATE_MARKER_WAIT_S)

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
        for k, age in ages.items():
            if age > cfg.stale_s:
                raise _AbortError("telemetry_stale", f"no {k} telemetry for {age:.3f} s (limit {cfg.stale_s:g} s)")
        self._supervision_verdict()
        self._measure_link(t_v)

    def swing_amplitude(self, est: ControlState) -> float:
        """The load's swing amplitude in ``est`` (rad): the angle an undamped pendulum with this angle and rate
        would reach, both axes together (``sqrt(a^2 + (a' / w)^2)``, ``w`` the pendulum frequency)."""
        return swing_amplitude(est.alpha_x, est.alpha_y, est.alpha_x_rate, est.alpha_y_rate, self.k.g / self.k.l)

    def _settled(self, est: ControlState | None, past_end_s: float) -> bool:
        """After the reference's end (``past_end_s`` s ago): whether the flight may end now. First the reference's
        smooth stop, if it has one (``offboard.control.reference_stop``, ``stop_s``: a reference still moving at
        its end is brought to rest, so that the autopilot's hold is given a vehicle at rest); then the load's swing
        amplitude within ``settle_swing_rad``, or ``settle_s`` more has passed (reported either way). A flight that
        ends with the vehicle moving or the load swinging would otherwise hand them to the autopilot's hold, which
        brakes on its own and does not damp the swing (PX4's and ArduPilot's position controllers know nothing of
        the load)."""
        cfg = self.cfg
        stop_s = float(getattr(self.reference, "stop_s", 0.0))
        amp = self.swing_amplitude(est) if est is not None else 0.0
        if past_end_s < stop_s:
            if not self._settling:
                self._settling = True
                self.event(
                    "phase",
                    f"end of the reference: stopping over {stop_s:.2f} s (the load swinging {amp:.3f} rad), then "
                    f"flying on until the swing is within {cfg.settle_swing_rad:g} rad (at most {cfg.settle_s:g} s)",
                )
            return False
        if amp <= cfg.settle_swing_rad:
            if self._settling:
                self.event("phase", f"the swing settled ({amp:.3f} rad) {past_end_s:.2f} s after the reference's end")
            return True
        if past_end_s > stop_s + cfg.settle_s:
            if cfg.settle_s > 0.0:
                self.event(
                    "settle_timeout",
                    f"the load still swings {amp:.3f} rad {stop_s + cfg.settle_s:g} s after the reference's end "
                    f"(settle bound {cfg.settle_swing_rad:g} rad): handing over anyway",
                )
            return True
        if not self._settling:
            self._settling = True
            self.event(
                "phase",
                f"end of the reference with the load swinging {amp:.3f} rad: flying on until it is within "
                f"{cfg.settle_swing_rad:g} rad (at most {cfg.settle_s:g} s)",
            )
        return False

    _settling = False

    def _check_swing(self, est: ControlState) -> None:
        cfg = self.cfg
        if not est.is_finite():
            raise _AbortError("estimator_divergence", "the estimate is not finite")
        p = self.last_pos
        if p is not None:
            l = self.k.l
            ex = est.fx[0] - l * est.alpha_y - p.x
            ey = est.fy[0] - l * est.alpha_x - p.y
            ez = est.z - p.z
            d = math.sqrt(ex * ex + ey * ey + ez * ez)
            if d > cfg.divergence_m:
                raise _AbortError(
                    "estimator_divergence",
                    f"estimated position {d:.2f} m from the autopilot's (limit {cfg.divergence_m:g} m)",
                )
        swing = math.hypot(est.alpha_x, est.alpha_y)
        if swing > cfg.swing_limit_rad:
            raise _AbortError("swing_limit", f"estimated swing {swing:.3f} rad above {cfg.swing_limit_rad:g} rad")

    def _abort_action(self, ab: _AbortError) -> str:
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

    def _finish(self, action: str, reason: str) -> str:
        """Leave offboard control: request hold / land while streaming hover setpoints, paced at the loop rate,
        until the heartbeat shows it (bounded by ``exit_timeout_s``, vehicle time in lockstep), then, for land,
        wait for the disarm. ``action`` ``none``: the vehicle has left the loop's control already (a pilot or a
        failsafe took over, or it disarmed): nothing is requested and nothing streamed."""
        self.supervisor.release()
        self._finishing = True
        v = self.conn.vehicle
        if action == "none":
            mode = mode_name(self.mgr.flavour, v.custom_mode) if v is not None else "unknown"
            self.event("exit", f"left to the vehicle: {reason}")
            state = f"in {mode}, {'armed' if v is not None and v.armed else 'disarmed'} (not commanded by slung)"
            self.event("exit_done", state)
            return state
        role = "hold" if action == "hold" else "land"
        self.event("exit", f"{role}: {reason}")
        self.mgr.send_mode_no_wait(role)
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


def prefuse_lead(period: float) -> float:
    """How far ahead of a tick's time (s) the filter fuses between ticks (``MeasuredKalmanEstimator.prefuse``): the
    next tick's time, a period later, less half a millisecond so that no record on the 1 ms grid of ``time_boot_ms``
    lies on the cut (the live loop and ``slung replay`` then select the same records even if their periods differ
    in the last bits)."""
    return period - 0.0005


def estimate_ahead(estimator: Estimator, t_act: float) -> ControlState:
    """The estimate at ``t_act`` (s, vehicle time), the time the tick's setpoint will act. The filter's output
    predictor carries its state there with the commands it was given; the filter's fusion horizon was sized for
    the link (``FlightLoop._size_for_link``), so the measurements of a slow link are still fused. The one place the
    loop asks the filter for its prediction: a filter with its own forward prediction over a measured delay
    plugs in here."""
    return estimator.estimate(t_act)


def initial_guess(
    vehicle: Vehicle, att: Attitude | None, pos: PositionVelocity | None, load: LoadAngle | None
) -> ControlState:
    """The filter's prior from the latest telemetry (model frame, SI): the vehicle at rest at the measured position
    and velocity and attitude (0 where a message is missing), the swing from the cable-angle sensor (0 without
    one), every rate not measured 0, expressed in the flat outputs through ``estimators.model.flatness``. The live loop
    and ``slung replay`` both call it (the replay must rebuild the live filter bit for bit)."""
    k = flat_constants(vehicle)
    x = y = z = vx = vy = vz = 0.0
    if pos is not None:
        x, y, z, vx, vy, vz = pos.x, pos.y, pos.z, pos.vx, pos.vy, pos.vz
    phi = theta = psi = 0.0
    if att is not None:
        phi, theta, psi = att.phi, att.theta, att.psi
    ax = ay = 0.0
    if load is not None:
        ax, ay = load.alpha_x, load.alpha_y
    nx, ny, nxd, nyd = world_tilt(phi, theta, psi, 0.0, 0.0, 0.0)
    return ControlState(
        flat_chain(k, x, vx, ay, 0.0, nx, nxd),
        flat_chain(k, y, vy, ax, 0.0, ny, nyd),
        z,
        vz,
        phi,
        theta,
        psi,
        0.0,
        0.0,
        0.0,
        ax,
        ay,
        0.0,
        0.0,
    )


def _fileno(conn: MavConnection) -> int | None:
    port = getattr(conn.conn, "port", None)
    try:
        return port.fileno() if port is not None else conn.conn.fd
    except Exception:
        return None


def _autopilot_dict(mapper: CommandMapper) -> dict[str, Any]:
    a = mapper.autopilot
    return {
        "flavour": a.flavour,
        "attitude_p": list(a.attitude_p),
        "rate_bandwidth": list(a.rate_bandwidth),
        "hover_thrust_norm": a.hover_thrust_norm,
        "angle_boost": a.angle_boost,
        "rate_integral": list(a.rate_integral),
        "integral_limit": a.integral_limit,
        "unit_torque": None if a.unit_torque is None else list(a.unit_torque),
    }


__all__ = [
    "DEFAULT_RATE_HZ",
    "LIVE_COL",
    "LIVE_COLUMNS",
    "RATE_MAX_HZ",
    "RATE_MIN_HZ",
    "ActuatorLag",
    "FlightLoop",
    "FlightResult",
    "LoopConfig",
    "LoopEvent",
    "LoopStats",
    "estimate_ahead",
    "initial_guess",
    "prefuse_lead",
]
