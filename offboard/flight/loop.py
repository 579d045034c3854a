"""The real-time offboard loop: telemetry -> Kalman filter -> sliding-mode controller -> setpoint, at a fixed rate,
with watchdogs, signal handling and loop statistics. Single-threaded; the same estimator and controller code as
``slung sim`` (``estimators.filters.factory.make_estimator``, ``offboard.control.smc.step``).

Pacing
    ``realtime`` (default): the loop asks the autopilot for ATTITUDE at ``rate_hz`` and runs one tick as soon as
    an ATTITUDE arrives (so the telemetry-to-setpoint latency is the compute time, not up to a period), each tick
    in a slot of a nominal grid one period apart: on the first ATTITUDE no earlier than half a period before the
    slot, else on its deadline half a period after it, so that a jittered link keeps the nominal rate
    (``offboard.flight.tick_pacing``). The
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
    - ``telemetry_stale``: no ATTITUDE or no position for longer than the staleness limit (wall time in real
      time, vehicle time in lockstep): derived from the link's gaps measured in the hold before control, within
      ``stale_s``..``stale_ceiling_s`` (default 0.5..1 s; ``offboard.flight.staleness``); a shorter gap is flown
      on the filter's prediction, and reported (``telemetry_gap``) when longer than any the hold showed;
    - ``estimator_divergence``: a non-finite estimate, or the estimated vehicle position more than
      ``divergence_m`` (default 1 m) from the autopilot's latest position;
    - ``swing_limit``: estimated swing ``hypot(alpha_x, alpha_y)`` above ``swing_limit_rad`` (default 0.8 rad);
    - ``loop_overrun``: one estimator update took longer than the staleness limit (an overloaded computer, or the filter
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
deadlines: ticks whose setpoint left more than a quarter period after their slot's deadline, or whose compute
time exceeded a period (``offboard.flight.tick_pacing``).

Where each job lives: :class:`FlightLoop` (this module) holds the flight's state and runs it from preflight to
the end (``run``); its jobs are mixins over that one state, each in its own module: the link and supervision
(reading and routing messages, waiting, the vehicle clock, the watchdogs, signals) in
``offboard.flight.loop_link``, the flight phases before control (preflight, take-off point, priming, approach,
sizing for the link) in ``offboard.flight.loop_phases``, the control phase (the tick loop, settling, the
estimate's checks) in ``offboard.flight.loop_tick``, the outputs (setpoints on the wire, the hand-over) in
``offboard.flight.loop_output``. What stands alone is elsewhere: its configuration and records in
``offboard.flight.loop_records``, the approach's settling checks in ``offboard.flight.start_checks``, the tick in
``offboard.control.tick``, supervision in ``offboard.flight.supervisor``, the link in ``offboard.flight.link``.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from estimators.filters.factory import Estimator
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants
from estimators.model.measurements import Attitude, LoadAngle, Measurement, PositionVelocity
from estimators.model.vehicle import Vehicle
from offboard.control import smc, smc_attitude
from offboard.control.controllers.protocol import Controller
from offboard.control.controllers.sliding_mode import law_for
from offboard.control.tick import ActuatorLag
from offboard.flight.attitude_mapping import inner_loop_of
from offboard.flight.command_mapping import CommandMapper
from offboard.flight.dropped_data import DroppedData
from offboard.flight.hover_thrust_learning import HoverThrustLearner
from offboard.flight.latency import LinkLatency
from offboard.flight.link.connection import MavConnection
from offboard.flight.link.management import Manager, custom_mode
from offboard.flight.link.telemetry import TelemetryDecoder
from offboard.flight.load_identification import InFlightLoadId
from offboard.flight.loop_identify import LoadIdentificationPhase
from offboard.flight.loop_link import FlightAbortError, LinkSupervision, _fileno
from offboard.flight.loop_output import LoopOutputs
from offboard.flight.loop_phases import FlightPhases, initial_guess
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
from offboard.flight.loop_tick import TickLoop, estimate_ahead, prefuse_lead
from offboard.flight.setpoint_echo import SetpointEcho
from offboard.flight.staleness import Staleness
from offboard.flight.supervisor import Supervisor

log = logging.getLogger("offboard.flight.loop")


class FlightLoop(LinkSupervision, FlightPhases, LoadIdentificationPhase, TickLoop, LoopOutputs):
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
        rebuild_for: Callable[[Vehicle, bool], tuple[Any, Callable[..., Estimator]]] | None = None,
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
        #: the staleness limit from the link's gaps in the hold (``offboard.flight.staleness``)
        self.staleness = Staleness(config.stale_s, config.stale_ceiling_s)
        #: refused data (non-finite telemetry, foreign senders, bad signatures) told as events (``dropped_data``)
        self.dropped = DroppedData()
        self._systems_told: set[int] = set()
        #: the autopilot's ATTITUDE_TARGET against the attitude setpoints sent (``setpoint_echo``): foreign setpoints
        self.echo = SetpointEcho()
        self._echo_on = False
        self._foreign_verdict: str | None = None
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
        #: the hover throttle learned in flight, from the end of the take-off on (``hover_thrust_learning``)
        self.hover_learner: HoverThrustLearner | None = None
        #: the load identified in flight (``LoadIdentificationPhase``; ``cfg.identify_load_s``), its metrics block,
        #: and how to rebuild the law's parameters and the filter for another vehicle (``slung fly``'s)
        self.load_id: InFlightLoadId | None = None
        self.load_block: dict[str, Any] | None = None
        self.rebuild_for = rebuild_for
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
                elif not robust and self._controller_given is None:  # (another controller: not this law's)
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
            self._start_hover_learning()
            assert self.last_pos is not None
            oz = self.ground_z or 0.0
            origin = (self.last_pos.x - ref0.fx[0], self.last_pos.y - ref0.fy[0])
            self.goal = (self.last_pos.x, self.last_pos.y, ref0.z[0] + oz, ref0.psi[0])
            self.staleness.measure()  # the link's gaps from here to the start of control set the staleness limit
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
            self._identification_hover()
            self._reread_hover_throttle()
            self.goal = None
            self.event("phase", self.staleness.derive())
            self._size_for_link()
            self._schedule_gains()
            self.initialize_estimator()
            if self._signal is not None:
                raise FlightAbortError("signal", f"signal {self._signal} during start-up", self.cfg.signal_action)
            self.event("phase", "offboard control started")
            self._fly(origin)
            self._ending_normally = True  # the exit is routine, not a warning
            end_state = self._finish(self.cfg.end_action, "end of the reference")
        except FlightAbortError as ab:
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
            self._enable_gc()  # whatever ended the flight, the collector is on again when run() returns
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
            supervision={**self.supervisor.summary(), "attitude_target": self.echo.summary()},
            latency=self.latency.summary(),
            filter_delay_s=self.filter_delay_s,
            gain_scale=self.gain_scale,
            reference_duration_s=self.duration,
            staleness=self.staleness.summary(),
            hover_learning=None if self.hover_learner is None else self.hover_learner.summary(),
            load_identification=self.load_block,
        )

    _prev_sent: float | None = None
    #: sample time (s, vehicle) of the newest attitude whose telemetry age was recorded (``_measure_link``)
    _aged_sample_t = -math.inf
    _ending_normally = False
    _finishing = False
    #: the control phase turned the garbage collector off and it is to be turned on again (``_enable_gc``)
    _gc_to_enable = False
    _settling = False


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
    "FlightAbortError",
    "FlightLoop",
    "FlightResult",
    "LoopConfig",
    "LoopEvent",
    "LoopStats",
    "estimate_ahead",
    "initial_guess",
    "prefuse_lead",
]
