"""The real-time offboard loop: telemetry -> Kalman filter -> sliding-mode controller -> setpoint, at a fixed rate,
with watchdogs, signal handling and loop statistics. Single-threaded; the same estimator and controller code as
``slung sim`` (``estimators.factory.make_estimator``, ``offboard.smc.step``).

Pacing
    ``realtime`` (default): the loop asks the autopilot for ATTITUDE at ``rate_hz`` and runs one tick as soon as
    each ATTITUDE arrives (so the telemetry-to-setpoint latency is the compute time, not up to a period); when
    no ATTITUDE arrives within 1.5 periods of the previous tick, the tick runs on that deadline instead. The
    vehicle time of a tick is the local time mapped through :class:`~offboard.link.connection.VehicleClock`.
    ``lockstep`` (the bundled emulator's handshake, ``docs/emulator.md``): every setpoint advances the emulated
    vehicle by one period; it then sends the telemetry of that period and a SYSTEM_TIME marker whose
    ``time_boot_ms`` is the new simulation time. One tick per marker, at the marker's time. A marker that does not
    come within ``lockstep_wait_s`` (lost packet) is replaced by a tick at the predicted time.
    Rate: default 250 Hz, accepted 20..1000 Hz (500 Hz is measured in ``bench/bench_loop.py``).

Each tick
    new measurements are pushed to the estimator as they are read; ``estimate(t)`` -> ``smc.step`` with the
    reference at ``t - t0`` (shifted horizontally so that it starts where the vehicle is when offboard control
    begins) -> :class:`~offboard.command_mapping.CommandMapper` -> encoded, checked and sent; the command is fed
    back to the estimator (``push_command``) as the motors deliver it (:class:`ActuatorLag`).

Watchdogs (each ends offboard control by switching the vehicle to its hold mode, logged with the reason)
    - ``telemetry_stale``: no ATTITUDE or no position for ``stale_s`` (default 0.1 s; wall time in real time,
      vehicle time in lockstep);
    - ``estimator_divergence``: a non-finite estimate, or the estimated vehicle position more than
      ``divergence_m`` (default 1 m) from the autopilot's latest position;
    - ``swing_limit``: estimated swing ``hypot(alpha_x, alpha_y)`` above ``swing_limit_rad`` (default 0.8 rad);
    - ``loop_overrun``: one estimator update took longer than ``stale_s`` (an overloaded computer, or the filter
      catching up after a stall): the loop can no longer keep its deadlines;
    - ``signal``: SIGINT / SIGTERM -> ``signal_action`` (hold or land).
    After a hold / land request the loop keeps streaming a hover setpoint until the heartbeat shows the new mode
    (or ``exit_timeout_s`` passes), so the vehicle is never left in offboard mode with a dead stream.

Statistics (:class:`LoopStats`): achieved rate, compute time (tick start to setpoint written) p50 / p99,
telemetry-to-setpoint latency (arrival of the newest telemetry used to setpoint written) p50 / p99, and missed
deadlines: ticks whose setpoint left more than 1.5 periods after the previous one, or whose compute time
exceeded a period.
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
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimators.control_state import ControlState
from estimators.flatness import flat_chain, flat_constants, world_tilt
from estimators.frames import model_euler_to_ned, model_to_ned_vector
from estimators.measurements import Attitude, LoadAngle, Measurement, PositionVelocity
from estimators.vehicle import Vehicle
from offboard import smc
from offboard.command_mapping import CommandMapper, setpoint_fields
from offboard.link.connection import MavConnection
from offboard.link.management import Manager
from offboard.link.setpoints import SetpointError, encode, encode_position
from offboard.link.telemetry import TelemetryDecoder

log = logging.getLogger(__name__)

RATE_MIN_HZ = 20.0
RATE_MAX_HZ = 1000.0
DEFAULT_RATE_HZ = 250.0

EST_NAMES = ("fx0", "fx1", "fx2", "fx3", "fx4", "fx5", "fy0", "fy1", "fy2", "fy3", "fy4", "fy5", "z", "z_rate",
             "phi", "theta", "psi", "phi_rate", "theta_rate", "psi_rate", "alpha_x", "alpha_y", "alpha_x_rate",
             "alpha_y_rate")
#: Columns of the flight log (``timeseries_live.csv``), all SI / rad, model frame, full float precision.
#: t_vehicle: tick time on the vehicle clock (s); t_ref: reference time (s); t_local: local monotonic time (s);
#: n_meas: measurements pushed to the estimator before this tick (cumulative, in tlog order); est_*: the estimate
#: the controller used; ref_*: reference jets (already shifted by the origin); int_*: controller integrals after
#: the step; cmd_*: controller output; sp0..sp8: the setpoint's wire fields (attitude: q w,x,y,z NED->FRD,
#: roll/pitch/yaw rate FRD, thrust, type_mask; actuator: roll, pitch, yaw, thrust, NaN x5); fallback: 1 when the
#: mapper replaced the command; compute_s, latency_s: tick timing; truth_*: the plant state (18 floats) when a
#: truth probe is attached (the demo), NaN otherwise, sampled before the tick's setpoint is sent (in lockstep the
#: plant is then exactly at t_vehicle); truth_tension: cable tension (N); truth_dist_*: the external disturbance
#: the plant receives from t_vehicle on (force on the vehicle, world N; yaw torque, N m), NaN if not told.
LIVE_COLUMNS: tuple[str, ...] = (
    "t_vehicle", "t_ref", "t_local", "n_meas",
    *("est_" + n for n in EST_NAMES),
    *(f"ref_fx{i}" for i in range(7)), *(f"ref_fy{i}" for i in range(7)),
    "ref_z0", "ref_z1", "ref_z2", "ref_psi0", "ref_psi1", "ref_psi2",
    "int_z", "int_psi", "int_fx", "int_fy",
    "cmd_thrust", "cmd_tau_phi", "cmd_tau_theta", "cmd_tau_psi", "cmd_s_z", "cmd_s_psi", "cmd_sigma_x",
    "cmd_sigma_y", "cmd_saturated", "cmd_valid",
    *(f"sp{i}" for i in range(9)),
    "fallback", "compute_s", "latency_s",
    *(f"truth_x{i}" for i in range(18)), "truth_tension",
    "truth_dist_fx", "truth_dist_fy", "truth_dist_fz", "truth_dist_tpsi",
)
LIVE_COL = {n: i for i, n in enumerate(LIVE_COLUMNS)}

#: truth_probe(t_vehicle) -> (18-float plant state, cable tension N[, (dist_fx, dist_fy, dist_fz, dist_tpsi)]) or None
TruthProbe = Callable[[float], "tuple[Any, ...] | None"]


@dataclass(frozen=True)
class LoopConfig:
    """Loop settings (SI). See the module docstring for each watchdog."""

    rate_hz: float = DEFAULT_RATE_HZ
    lockstep: bool = False
    lockstep_wait_s: float = 0.02
    stale_s: float = 0.1
    divergence_m: float = 1.0
    swing_limit_rad: float = 0.8
    end_action: str = "hold"
    signal_action: str = "hold"
    exit_timeout_s: float = 2.0
    prime_s: float = 1.0
    takeoff: bool = True
    telemetry_timeout_s: float = 10.0
    #: (stage, t_ref_start, t_ref_end): inject NaN into "measurement", "estimate", "reference" or "command"
    #: during that window (tests of the no-NaN-on-the-wire guarantee)
    inject_nan: tuple[tuple[str, float, float], ...] = ()

    def validate(self) -> None:
        """ValueError for settings out of their documented range."""
        if not (RATE_MIN_HZ <= self.rate_hz <= RATE_MAX_HZ):
            raise ValueError(f"rate must be within {RATE_MIN_HZ:g}..{RATE_MAX_HZ:g} Hz, got {self.rate_hz:g}")
        if not (0.01 <= self.stale_s <= 5.0):
            raise ValueError(f"staleness limit must be within 0.01..5 s, got {self.stale_s:g}")
        for a in (self.end_action, self.signal_action):
            if a not in ("hold", "land"):
                raise ValueError(f"end action must be hold or land, got {a!r}")
        if self.prime_s < 1.0:
            raise ValueError("the setpoint stream must be primed for at least 1 s before the mode switch")


@dataclass
class LoopEvent:
    """Something the loop did or saw: vehicle time and local time (s), kind, reason."""

    t_vehicle: float
    t_local: float
    kind: str
    reason: str


@dataclass
class LoopStats:
    """Timing figures of the flight phase (s unless stated)."""

    ticks: int = 0
    elapsed_s: float = 0.0
    compute: list[float] = field(default_factory=list)
    estimator: list[float] = field(default_factory=list)
    latency: list[float] = field(default_factory=list)
    gaps: list[float] = field(default_factory=list)
    deadline_ticks: int = 0
    missed: int = 0
    sent_bytes: int = 0

    def summary(self, rate_hz: float) -> dict[str, Any]:
        """The ``loop`` block of metrics.json (times in microseconds)."""

        def pct(v: list[float], q: float) -> float | None:
            return float(np.percentile(np.asarray(v) * 1e6, q)) if v else None

        return {
            "rate_hz_requested": rate_hz,
            "rate_hz_achieved": self.ticks / self.elapsed_s if self.elapsed_s > 0 else None,
            "ticks": self.ticks,
            "elapsed_s": self.elapsed_s,
            "compute_us_p50": pct(self.compute, 50), "compute_us_p99": pct(self.compute, 99),
            "compute_us_max": pct(self.compute, 100),
            "estimator_us_p50": pct(self.estimator, 50), "estimator_us_p99": pct(self.estimator, 99),
            "latency_us_p50": pct(self.latency, 50), "latency_us_p99": pct(self.latency, 99),
            "latency_samples": len(self.latency),
            "gap_us_p50": pct(self.gaps, 50), "gap_us_p99": pct(self.gaps, 99), "gap_us_max": pct(self.gaps, 100),
            "deadline_ticks": self.deadline_ticks,
            "missed_deadlines": self.missed,
            "missed_fraction": self.missed / self.ticks if self.ticks else None,
        }


@dataclass
class FlightResult:
    """What a flight produced (the caller writes the files)."""

    rows: list[tuple[float, ...]]
    events: list[LoopEvent]
    stats: LoopStats
    ended_by: str
    end_state: str
    origin: tuple[float, float]
    estimator_stats: dict[str, int]
    mapper_events: list[Any]
    management_events: list[Any]
    warnings: list[str]
    autopilot: dict[str, Any]
    load_sensor: bool
    telemetry_counts: dict[str, int]


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

    def __init__(self, conn: MavConnection, vehicle: Vehicle, reference: Any, duration: float,
                 params: smc.ControllerParams, mapper: CommandMapper, estimator: Any, config: LoopConfig,
                 truth_probe: TruthProbe | None = None, manager: Manager | None = None,
                 estimator_factory: Callable[[], Any] | None = None,
                 on_reference_start: Callable[[float], None] | None = None) -> None:
        config.validate()
        self.conn = conn
        self.vehicle = vehicle
        self.reference = reference
        self.duration = duration
        self.params = params
        self.mapper = mapper
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
        self.home_alt: float | None = None
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
            if kind == "SYSTEM_TIME" and self.cfg.lockstep:
                self.marker_t = msg.time_boot_ms * 1e-3
                self.trigger_local = r.t_local
                self._triggered = True
                continue
            if kind == "GLOBAL_POSITION_INT" and self.home_alt is None:
                self.home_alt = (msg.alt - msg.relative_alt) * 1e-3
                continue
            m = self.decoder.decode(msg)
            if m is None:
                continue
            if self._inject and isinstance(m, Attitude) and self._injected("measurement", m.t - self._t0_meas):
                m = m._replace(phi=math.nan)
            self.last_rx_local[type(m).__name__] = r.t_local
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
            elif isinstance(m, LoadAngle):
                self.last_load = m
            if self.estimator_ready:
                self.estimator.push(m)
                self.n_meas += 1

    def _wait(self, timeout: float) -> bool:
        """Block up to ``timeout`` s for a trigger; True if one arrived."""
        t_end = time.monotonic() + timeout
        while True:
            if self._read():
                return True
            left = t_end - time.monotonic()
            if left <= 0.0 or self._signal is not None:
                return False
            if self._fd is not None:
                select.select([self._fd], [], [], min(left, 0.05))
            else:
                time.sleep(min(left, 0.0005))

    def height(self) -> float | None:
        """Latest height above home from telemetry (m), None if none yet."""
        return None if self.last_pos is None else self.last_pos.z

    def _send(self, sp: Any, t: float) -> None:
        try:
            msg = encode(self.conn.mav, sp, max(t, 0.0), *self.target)
        except SetpointError as exc:  # the mapper should make this impossible; never send it anyway
            self.event("setpoint_refused", str(exc))
            sp = self.mapper.hover_setpoint(self.last_att.psi if self.last_att else 0.0)
            msg = encode(self.conn.mav, sp, max(t, 0.0), *self.target)
        self.stats.sent_bytes += len(self.conn.send(msg))
        self.last_sp = sp
        self.last_send_local = time.monotonic()

    def _hover_sp(self) -> Any:
        return self.mapper.hover_setpoint(self.last_att.psi if self.last_att is not None else 0.0)

    def _send_goal(self) -> None:
        assert self.goal is not None
        x, y, z, psi = self.goal
        n, e, d = model_to_ned_vector(x, y, z)
        yaw = model_euler_to_ned(0.0, 0.0, psi)[2]
        self.stats.sent_bytes += len(self.conn.send(encode_position(self.conn.mav, n, e, d, yaw, self.t_vehicle,
                                                                    *self.target)))
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
        """Stream hover setpoints for ``seconds`` of vehicle time (PX4 needs the stream before the switch)."""
        start = self._now_vehicle()
        n = 0
        while self._now_vehicle() - start < seconds:
            self.stream_hover()
            n += 1
            if self._signal is not None:
                raise _AbortError("signal", f"signal {self._signal} while priming", self.cfg.signal_action)
        self.event("phase", f"primed the setpoint stream: {n} setpoints over {seconds:g} s")

    def _approach(self, settle_s: float = 0.5, timeout_s: float = 30.0) -> None:
        """Hold the position goal (the reference's start) until, averaged over the last ``settle_s`` of vehicle
        time, the vehicle is within 1 cm of it, slower than 3 cm/s, with its swing under 0.02 rad.

        The averages make the criterion noise-aware: single samples of a real (or emulated ``px4-typical``)
        estimate scatter by 2-3 cm and 3 cm/s, above the thresholds, while the mean of the ~50 position and
        ~125 load-angle samples of 0.5 s scatters by a few millimetres; a vehicle that is really still off the
        goal or moving still fails it."""
        assert self.goal is not None
        gx, gy, gz, _ = self.goal
        start = self._now_vehicle()
        # window entries are stamped with the loop's clock (``_now_vehicle``: vehicle time in lockstep, local time
        # in real time); a new sample is one with a newer sample time
        pos: deque[tuple[float, float, float, float, float, float, float]] = deque()
        swing: deque[tuple[float, float, float]] = deque()
        last_p = last_l = -math.inf
        while True:
            self.stream_hover()
            now = self._now_vehicle()
            p, ld = self.last_pos, self.last_load
            if p is not None and p.t > last_p:
                last_p = p.t
                pos.append((now, p.x, p.y, p.z, p.vx, p.vy, p.vz))
            if ld is not None and ld.t > last_l:
                last_l = ld.t
                swing.append((now, ld.alpha_x, ld.alpha_y))
            for q in (pos, swing):
                while q and q[0][0] < now - settle_s:
                    q.popleft()
            if _settled(pos, swing, gx, gy, gz, now - start >= settle_s, ld is not None):
                self.event("phase", f"at the start of the reference after {now - start:.2f} s")
                return
            if now - start > timeout_s:
                self.event("phase", f"start of the reference not reached within {timeout_s:g} s: starting anyway")
                return
            if self._signal is not None:
                raise _AbortError("signal", f"signal {self._signal} before the flight", self.cfg.signal_action)

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
        streams = {"ATTITUDE": rate, "LOCAL_POSITION_NED": min(rate, 100.0), "HIGHRES_IMU": rate,
                   "DEBUG_VECT": min(rate, 250.0)}
        self.mgr.request_streams(streams, idle=self._idle_read)
        self.conn.request_timesync(time.monotonic())
        ok = self.mgr.wait_for(lambda: (self._read() or True) and self.last_att is not None
                               and self.last_pos is not None, self.cfg.telemetry_timeout_s)
        if not ok:
            got = ", ".join(sorted(self.last_rx_local)) or "nothing"
            raise UserError(f"no fresh attitude and position telemetry within {self.cfg.telemetry_timeout_s:g} s "
                            f"(got: {got})")
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
            if self.cfg.takeoff:
                h0 = self.height() or 0.0
                if h0 < ref0.z[0] - 0.3:
                    prime = self.stream_hover if self.mgr.flavour == "px4" else self._idle_read
                    self.mgr.takeoff(ref0.z[0], self.home_alt, self.height, idle=prime)
            assert self.last_pos is not None
            origin = (self.last_pos.x - ref0.fx[0], self.last_pos.y - ref0.fy[0])
            self.goal = (self.last_pos.x, self.last_pos.y, ref0.z[0], ref0.psi[0])
            self._prime(self.cfg.prime_s if self.mgr.flavour == "px4" else 0.0)
            if not self.mgr.set_mode("offboard", idle=self.stream_hover):
                from estimators.errors import UserError

                raise UserError("the autopilot refused offboard control: " + "; ".join(self.conn.statustexts[-3:]))
            self._approach()
            self.goal = None
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
            end_state = self._finish(ab.action, ab.reason)
        finally:
            self._restore_signals(old)
        return FlightResult(self.rows, self.events, self.stats, ended_by, end_state, origin,
                            dict(self.estimator.stats()) if self.estimator_ready else {}, self.mapper.events,
                            self.mgr.events, self.mgr.warnings, _autopilot_dict(self.mapper),
                            self.last_load is not None, dict(self.decoder.counts))

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
        self._t0_meas = t0
        if self.on_reference_start is not None:  # before the first command: the harness starts its clocks at t0
            self.on_reference_start(t0)
        memory = smc.ControllerMemory()
        wall0 = time.monotonic()
        last_marker = self.marker_t
        stats = self.stats
        t_v = t0
        # no cyclic garbage collection during the flight: a full collection over the growing log costs
        # milliseconds, a missed deadline; the loop's objects are acyclic and freed by reference counting.
        # No collection here either: in a large process (a test session, a host application) it stalls for
        # 0.1 s or more between the last telemetry read and the first tick, and the stale-telemetry watchdog
        # ends the flight before it starts; preflight collects, where nothing is streamed yet. Freezing is O(1).
        gc.freeze()
        gc_was_enabled = gc.isenabled()
        gc.disable()
        try:
            self._fly_ticks(t0, t_v, last_marker, origin, memory, wall0)
        finally:
            stats.elapsed_s = time.monotonic() - wall0
            if gc_was_enabled:
                gc.enable()
            gc.unfreeze()

    def _fly_ticks(self, t0: float, t_v: float, last_marker: float | None, origin: tuple[float, float],
                   memory: smc.ControllerMemory, wall0: float) -> None:
        cfg = self.cfg
        period = self.period
        lockstep = cfg.lockstep
        ox, oy = origin
        step = smc.step
        mapper = self.mapper
        est_f = self.estimator
        probe = self.truth_probe
        nan9 = (math.nan,) * 9
        lag = ActuatorLag(self.vehicle.motor_time_constant)
        nan23 = (math.nan,) * 23
        nan4 = (math.nan,) * 4
        stats = self.stats
        while True:
            # ---- wait for the tick's trigger -------------------------------------------------------------
            if lockstep:
                got = self._wait(cfg.lockstep_wait_s) and self.marker_t != last_marker
                if got:
                    t_v = self.marker_t  # type: ignore[assignment]
                    last_marker = self.marker_t
                else:
                    t_v = t_v + period
                    stats.deadline_ticks += 1
                    self.trigger_local = None
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
            # the demo's truth (metrics only), before this tick's setpoint lets a lockstep plant move on
            truth = probe(t_v) if probe is not None and t_v - t0 <= self.duration + 1e-9 else None
            tick_start = time.monotonic()
            perf0 = time.perf_counter()
            self.t_vehicle = t_v
            t_ref = t_v - t0
            if self._signal is not None:
                raise _AbortError("signal", f"signal {self._signal} received", cfg.signal_action)
            if t_ref > self.duration + 1e-9:
                break
            self._watchdogs(t_v, tick_start)
            # ---- estimate, reference, control ------------------------------------------------------------
            pe = time.perf_counter()
            est = est_f.estimate(t_v)
            te = time.perf_counter() - pe
            stats.estimator.append(te)
            if te > cfg.stale_s:
                raise _AbortError("loop_overrun", f"one filter update took {te:.3f} s (limit {cfg.stale_s:g} s)")
            if self._inject and self._injected("estimate", t_ref):
                est = est._replace(theta=math.nan)
            ref = self.reference.sample(t_ref)
            rfx = (ref.fx[0] + ox, *ref.fx[1:])
            rfy = (ref.fy[0] + oy, *ref.fy[1:])
            if self._inject and self._injected("reference", t_ref):
                rfx = (math.nan, *rfx[1:])
            cmd, memory = step(t_ref, est, rfx, rfy, ref.z, ref.psi, memory, self.params)
            if self._inject and self._injected("command", t_ref):
                cmd = cmd._replace(tau_phi=math.inf, thrust=math.nan)
            nfb = mapper.fallbacks
            sp = mapper.map(t_ref, cmd, est)
            self._send(sp, t_ref)
            if math.isfinite(cmd.thrust) and math.isfinite(cmd.tau_phi) and math.isfinite(cmd.tau_theta) \
                    and math.isfinite(cmd.tau_psi):
                est_f.push_command(t_v, *lag(t_v, cmd.thrust, (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)))
            sent = time.monotonic()
            compute = time.perf_counter() - perf0
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
            self.rows.append((t_v, t_ref, tick_start, float(self.n_meas), *est[0], *est[1], *est[2:],
                              *rfx, *rfy, *ref.z[:3], *ref.psi[:3], memory.int_z, memory.int_psi, memory.int_fx,
                              memory.int_fy, *cmd[:8], float(cmd.saturated), float(cmd.valid),
                              *(spf + nan9[len(spf):]), float(mapper.fallbacks != nfb), compute, latency, *tr))
            self._check_swing(est)

    _prev_sent: float | None = None
    _ending_normally = False

    def _watchdogs(self, t_v: float, now: float) -> None:
        cfg = self.cfg
        if cfg.lockstep:
            ages = {k: t_v - m.t for k, m in (("Attitude", self.last_att), ("PositionVelocity", self.last_pos))
                    if m is not None}
        else:
            ages = {k: now - self.last_rx_local.get(k, -math.inf) for k in ("Attitude", "PositionVelocity")}
        for k, age in ages.items():
            if age > cfg.stale_s:
                raise _AbortError("telemetry_stale", f"no {k} telemetry for {age:.3f} s (limit {cfg.stale_s:g} s)")

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
                raise _AbortError("estimator_divergence",
                             f"estimated position {d:.2f} m from the autopilot's (limit {cfg.divergence_m:g} m)")
        swing = math.hypot(est.alpha_x, est.alpha_y)
        if swing > cfg.swing_limit_rad:
            raise _AbortError("swing_limit", f"estimated swing {swing:.3f} rad above {cfg.swing_limit_rad:g} rad")

    def _finish(self, action: str, reason: str) -> str:
        """Leave offboard control: request hold / land while streaming hover setpoints until the heartbeat
        shows it (bounded by ``exit_timeout_s``), then, for land, wait for the disarm."""
        role = "hold" if action == "hold" else "land"
        self.event("exit", f"{role}: {reason}")
        self.mgr.send_mode_no_wait(role)
        t_end = time.monotonic() + self.cfg.exit_timeout_s
        last_cmd = time.monotonic()
        while time.monotonic() < t_end and not self.mgr.in_mode(role):
            self._send(self._hover_sp(), self.t_vehicle)
            if self.cfg.lockstep:
                self._wait(min(self.cfg.lockstep_wait_s, 0.02))
            else:
                self._wait(self.period)
            if time.monotonic() - last_cmd > 0.1:
                self.mgr.send_mode_no_wait(role)
                last_cmd = time.monotonic()
        state = role if self.mgr.in_mode(role) else f"{role} requested (not confirmed)"
        self.event("exit_done", state)
        if role == "land" and self.mgr.in_mode(role):
            v = self.conn.vehicle
            if self.mgr.wait_for(lambda: v is not None and not v.armed, 30.0):
                state = "landed, disarmed"
                self.event("exit_done", state)
        return state

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


class ActuatorLag:
    """The thrust and torques the motors deliver for a stream of commands: a first-order lag with the vehicle
    file's ``motor_time_constant`` (s), discretized exactly between calls (``a = 1 - exp(-dt / tau)``). This is
    the command the filter is given (``push_command``), in the live loop and in ``slung replay``: with the
    setpoint itself, the filter's vertical model runs 20 ms ahead of the motors, and under the sliding-mode
    thrust switching (+-1.5 N from tick to tick) the accelerometer then disagrees with it by more than its gate
    on one update in ten, which lets the height estimate drift by centimetres (measured over the paper scenario
    with px4-typical sensors: 3629 vertical accelerometer updates gated, height tracking 5.7 mm RMS; with the
    lag 8 gated, 2.9 mm; ``slung sim``, whose plant applies the command without lag, 3.2 mm). The first call
    returns its command unchanged (the state starts there); N, N m, model frame."""

    __slots__ = ("_a", "_dt", "_s", "_t", "_tau")

    def __init__(self, time_constant_s: float) -> None:
        if not (math.isfinite(time_constant_s) and time_constant_s >= 0.0):
            raise ValueError(f"motor time constant must be a finite number >= 0 s, got {time_constant_s!r}")
        self._tau = time_constant_s
        self._t: float | None = None
        self._s = [0.0, 0.0, 0.0, 0.0]
        self._dt = -1.0
        self._a = 1.0

    def __call__(self, t: float, thrust: float, tau: tuple[float, float, float]) -> tuple[float, tuple[
            float, float, float]]:
        """Delivered (thrust N, (tau_phi, tau_theta, tau_psi) N m) at time ``t`` (s) after commanding these
        finite values from ``t`` on."""
        s = self._s
        if self._t is None or self._tau == 0.0:
            s[0], s[1], s[2], s[3] = thrust, tau[0], tau[1], tau[2]
        else:
            dt = t - self._t
            if dt != self._dt:
                self._dt = dt
                self._a = 1.0 - math.exp(-dt / self._tau) if dt > 0.0 else 0.0
            a = self._a
            s[0] += a * (thrust - s[0])
            s[1] += a * (tau[0] - s[1])
            s[2] += a * (tau[1] - s[2])
            s[3] += a * (tau[2] - s[3])
        self._t = t
        return s[0], (s[1], s[2], s[3])


def initial_guess(vehicle: Vehicle, att: Attitude | None, pos: PositionVelocity | None,
                  load: LoadAngle | None) -> ControlState:
    """The filter's prior from the latest telemetry (model frame, SI): the vehicle at rest at the measured position
    and velocity and attitude (0 where a message is missing), the swing from the cable-angle sensor (0 without
    one), every rate not measured 0, expressed in the flat outputs through ``estimators.flatness``. The live loop
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
    return ControlState(flat_chain(k, x, vx, ay, 0.0, nx, nxd), flat_chain(k, y, vy, ax, 0.0, ny, nyd),
                        z, vz, phi, theta, psi, 0.0, 0.0, 0.0, ax, ay, 0.0, 0.0)


def _settled(pos: Any, swing: Any, gx: float, gy: float, gz: float, long_enough: bool, has_load: bool) -> bool:
    """The approach criterion of :meth:`FlightLoop._approach` on the windows of position samples
    (t, x, y, z, vx, vy, vz) and load-angle samples (t, alpha_x, alpha_y): means within 1 cm, 3 cm/s, 0.02 rad."""
    if not long_enough or len(pos) < 3 or (has_load and len(swing) < 3):
        return False
    n = len(pos)
    mx, my, mz, mvx, mvy, mvz = (sum(s[i] for s in pos) / n for i in range(1, 7))
    if math.sqrt((mx - gx) ** 2 + (my - gy) ** 2 + (mz - gz) ** 2) >= 0.01:
        return False
    if math.sqrt(mvx * mvx + mvy * mvy + mvz * mvz) >= 0.03:
        return False
    if has_load:
        k = len(swing)
        if math.hypot(sum(s[1] for s in swing) / k, sum(s[2] for s in swing) / k) >= 0.02:
            return False
    return True


def _fileno(conn: MavConnection) -> int | None:
    port = getattr(conn.conn, "port", None)
    try:
        return port.fileno() if port is not None else conn.conn.fd
    except Exception:
        return None


def _autopilot_dict(mapper: CommandMapper) -> dict[str, Any]:
    a = mapper.autopilot
    return {"flavour": a.flavour, "attitude_p": list(a.attitude_p), "rate_bandwidth": list(a.rate_bandwidth),
            "hover_thrust_norm": a.hover_thrust_norm, "angle_boost": a.angle_boost,
            "rate_integral": list(a.rate_integral), "integral_limit": a.integral_limit}


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
    "initial_guess",
]
