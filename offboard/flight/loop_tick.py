"""The live loop's control phase (mixed into :class:`offboard.flight.loop.FlightLoop`, whose state it reads and
writes): the tick loop (wait for the trigger, watchdogs, ``offboard.control.tick.ControlTick``, the setpoint on the
wire, statistics and the tick log), the lockstep step markers, the settling after the reference's end, the
estimate's checks (divergence, swing) and the fault-injection hook.
"""

from __future__ import annotations

import gc
import math
import time
from typing import Any

from estimators.filters.factory import Estimator
from estimators.model.cable import swing_amplitude
from estimators.model.control_state import ControlState
from offboard.control.controllers.sliding_mode import law_for
from offboard.control.tick import ActuatorLag, ControlTick
from offboard.flight.command_mapping import setpoint_fields
from offboard.flight.load_ground import LoadGroundWatch
from offboard.flight.loop_link import FlightAbortError
from offboard.flight.setpoint_echo import ATTITUDE_IGNORE
from offboard.flight.tick_pacing import TickPacer

#: lockstep: how much longer (wall s) a tick waits for the next step marker after a late one (``_next_step``)
LATE_MARKER_WAIT_S = 0.25


class TickLoop:
    """The control phase of :class:`~offboard.flight.loop.FlightLoop` (a mixin: the state is the loop's)."""

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
        self._echo_on = True  # from now on the setpoints are the law's: the autopilot's target must follow them
        try:
            self._fly_ticks(t0, t_v, last_marker, origin, wall0)
        finally:
            stats.elapsed_s = time.monotonic() - wall0
            gc.unfreeze()
            # the collector comes back once the hand-over is asked for (``_control_ended``), not before: its first
            # collection sweeps everything the flight allocated (5 ms here) and must not delay the hold request
            self._gc_to_enable = gc_was_enabled

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
        load_watch = LoadGroundWatch(self.vehicle.cable_length, oz) if self.vehicle.mass_load > 0.0 else None
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
        pacer = TickPacer(period)  # real time: each tick's slot on the nominal grid (offboard.flight.tick_pacing)
        got = False
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
                got = self._await_slot(pacer)
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
                raise FlightAbortError("signal", f"signal {self._signal} received", cfg.signal_action)
            if t_ref > self.duration + 1e-9 and self._settled(last_est, t_ref - self.duration):
                break
            self._watchdogs(t_obs, tick_start)
            # ---- estimate (at the action time), reference, control, map, feed the filter (offboard.control.tick) ---
            nfb = mapper.fallbacks
            out = tick(t_v, t_ref)
            te = out.estimate_s
            stats.estimator.append(te)
            stale_s = self.staleness.limit_s
            if te > stale_s and not lockstep:  # in lockstep the vehicle waits for the setpoint: no deadline
                raise FlightAbortError("loop_overrun", f"one filter update took {te:.3f} s (limit {stale_s:.3g} s)")
            est, ref, rfx, rfy, rz, cmd, sp = out.est, out.ref, out.rfx, out.rfy, out.rz, out.cmd, out.setpoint
            if self._inject and self._injected("setpoint", t_ref):
                sp = sp._replace(thrust=math.nan)
            buf = self._send(sp, t_ref, log=False)
            sent = time.monotonic()
            compute = time.perf_counter() - perf0
            # the setpoint is on the wire: now its tlog record (a slow write must not delay the setpoint)
            self.conn.log_sent(buf, time.time())
            sp = self.last_sp  # what left (the hover setpoint if the encoder refused this one): what the log records
            spf = setpoint_fields(sp)
            if len(spf) == 9 and not int(spf[8]) & ATTITUDE_IGNORE:  # an attitude it flies: for the echo's comparison
                self.echo.sent(t_obs, spf[:4])
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
            if not lockstep:
                stats.missed += pacer.missed(sent, compute)
                pacer.ticked(sent, got)
            self._prev_sent = sent
            stats.ticks += 1
            tr = (*truth[0], truth[1], *(truth[2] if len(truth) > 2 else nan4)) if truth is not None else nan23
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
            self._report_dropped()  # off the path to the setpoint: a few counter reads
            self._check_swing(est)
            if load_watch is not None and (ground := load_watch.update(est)) is not None:
                self.event(*ground)  # a warning line and events.json (offboard.flight.load_ground)
            last_est = est
            v = self.supervisor.check_tracking(est.fx[0] - rfx[0], est.fy[0] - rfy[0], est.z - rz[0])
            if v is not None:
                raise FlightAbortError(v.kind, v.reason, v.action)

    def _await_slot(self, pacer: TickPacer) -> bool:
        """Real time: wait for this tick's moment (``offboard.flight.tick_pacing``): the first trigger no earlier than
        half a period before its slot, else its deadline; True if a trigger came. A pending signal ends the wait."""
        early, deadline = pacer.window(time.monotonic())
        got = False
        while True:
            now = time.monotonic()
            if (got and now >= early) or self._signal is not None:
                return got
            if now >= deadline:  # read what waits before ticking (after a stall of the loop its deadline is long past)
                return self._read() or got
            if self._wait((early if got else deadline) - now):
                got = True

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

    def _check_swing(self, est: ControlState) -> None:
        cfg = self.cfg
        if not est.is_finite():
            raise FlightAbortError("estimator_divergence", "the estimate is not finite")
        p = self.last_pos
        if p is not None:
            l = self.k.l
            ex = est.fx[0] - l * est.alpha_y - p.x
            ey = est.fy[0] - l * est.alpha_x - p.y
            ez = est.z - p.z
            d = math.sqrt(ex * ex + ey * ey + ez * ez)
            if d > cfg.divergence_m:
                raise FlightAbortError(
                    "estimator_divergence",
                    f"estimated position {d:.2f} m from the autopilot's (limit {cfg.divergence_m:g} m)",
                )
        swing = math.hypot(est.alpha_x, est.alpha_y)
        if swing > cfg.swing_limit_rad:
            raise FlightAbortError("swing_limit", f"estimated swing {swing:.3f} rad above {cfg.swing_limit_rad:g} rad")

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
