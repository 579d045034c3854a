"""The live loop's flight phases before control (mixed into :class:`offboard.flight.loop.FlightLoop`, whose state
it reads and writes): the pre-flight (streams, telemetry, the autopilot's model, the filter's warm-up), the take-off
point, the keep-alive stream, priming, the approach to the reference's start and its settling, the hover throttle
re-read, and at the start of control the filter's horizon and the torque-level law's gains sized for the measured
link; the filter's prior (:func:`initial_guess`, shared with ``slung replay``).
"""

from __future__ import annotations

import gc
import math
import time
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_chain, flat_constants, world_tilt
from estimators.model.measurements import Attitude, LoadAngle, PositionVelocity
from estimators.model.vehicle import Vehicle
from offboard.control import smc, smc_attitude
from offboard.control.delay_margin import gain_scale, loop_delay
from offboard.flight.command_mapping import CommandMapper
from offboard.flight.hover_thrust_learning import HoverThrustLearner
from offboard.flight.link.autopilot_model import choose_hover_throttle
from offboard.flight.loop_link import FlightAbortError
from offboard.flight.start_checks import offset_and_noise, settled, standard_error


class FlightPhases:
    """The phases of :class:`~offboard.flight.loop.FlightLoop` before control (a mixin: the state is the loop's)."""

    def preflight(self) -> None:
        """Streams, telemetry present and fresh, autopilot model, thrust semantics (ArduPilot)."""
        from estimators.errors import UserError

        rate = self.cfg.rate_hz
        streams = {
            "ATTITUDE": rate,
            "LOCAL_POSITION_NED": min(rate, 100.0),
            "HIGHRES_IMU": rate,
            "DEBUG_VECT": min(rate, 250.0),
            # the attitude the autopilot flies: compared with ours to tell another sender's setpoints (setpoint_echo)
            "ATTITUDE_TARGET": min(rate, 50.0),
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

    def _warm_up(self, t0: float, max_step_ms: int = 100, factory: Any = None) -> None:
        """Run a scratch filter (``estimator_factory``) through steps of 1..``max_step_ms`` ms (the lengths a
        real-time loop on the 1 ms vehicle clock produces), so that its per-step-length discretizations are
        computed before the flight, not in the first ticks (where each new length costs milliseconds and a slow
        tick makes longer, new steps: a spiral). The scratch filter is discarded. ``factory``: another filter's
        (the identified load's, ``loop_identify``) instead of the loop's."""
        factory = factory or self.estimator_factory
        if factory is None:
            return
        scratch = factory()  # a new instance shares the filter's class-level discretization cache
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

    def fix_ground(self) -> None:
        """Fix :attr:`ground_z`, the take-off point's local z, once, before the take-off decision.

        On the ground (disarmed, or the autopilot's height above home under 0.3 m or unknown) with a take-off to
        fly: the mean of the last position samples, where the vehicle sits. In the air (``--no-takeoff``, or a
        vehicle already flying): home as the autopilot reports it, the median of ``local z - relative_alt``. Without
        GLOBAL_POSITION_INT in the air: local z itself, with a warning."""
        if self.ground_z is not None:
            return
        # disarmed is on the ground whatever the height above home says: after a landing PX4 SITL's relative_alt
        # stayed 0.4-1.1 m (its home wandering), and the ground was taken from that home, 0.5-1 m off
        armed = self.conn.vehicle is not None and bool(self.conn.vehicle.armed)
        airborne = self.rel_alt is not None and self.rel_alt > 0.3 and armed
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

    def _abort_on_signal(self) -> None:
        """Raise the signal abort now if Ctrl-C / SIGTERM arrived: the management phases (stream requests, arming,
        the autopilot's take-off, the mode switch) wait in loops that call the idle callbacks below, and a signal
        must end them at once (hold or land from where the vehicle is), not after the take-off has finished."""
        if self._signal is not None:
            raise FlightAbortError("signal", f"signal {self._signal} before the flight", self.cfg.signal_action)

    def stream_hover(self) -> None:
        """Send one keep-alive setpoint (the position goal before control starts, else a hover attitude) and pace
        to the loop rate (management's idle callback while streaming)."""
        self._abort_on_signal()
        self._report_dropped()
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
                raise FlightAbortError("signal", f"signal {self._signal} while priming", self.cfg.signal_action)
        self.event("phase", f"primed the setpoint stream: {n} setpoints over {seconds:g} s")

    def _approach(self, settle_s: float = 0.5, timeout_s: float | None = None, noise_s: float = 3.0) -> None:
        """Hold the position goal (the reference's start) until, averaged over the last ``settle_s`` of vehicle
        time, the vehicle is at it, at rest and its swing small, each within what the telemetry's own scatter
        lets one tell (:func:`settled`: two standard errors of the mean, estimated over the last ``noise_s``, at
        least 1 cm, 3 cm/s, 0.02 rad), and the hover throttle learned in flight is trusted
        (:meth:`_hover_throttle_known`);
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
            at_start = fresh and settled(pos, swing, gx, gy, gz, now - start >= settle_s, ld is not None, noise)
            if at_start and self._hover_throttle_known():
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
                raise FlightAbortError("signal", f"signal {self._signal} before the flight", self.cfg.signal_action)

    def _start_hover_learning(self) -> None:
        """In the air (after the take-off, or at once with ``--no-takeoff``): learn the hover throttle from the
        autopilot's reported thrust and the vertical acceleration (``offboard.flight.hover_thrust_learning``), from
        the hover throttle the mapping flies with as the prior."""
        ap = self.mapper.autopilot
        prior = ap.hover_thrust_norm
        if prior is None:
            prior = self.vehicle.hover_throttle or self.vehicle.hover_thrust_normalized
        self.hover_learner = HoverThrustLearner(self.mgr.flavour, self.vehicle.gravity, prior, ap.angle_boost)
        self.hover_learner.start()

    def _hover_throttle_known(self) -> bool:
        """The hold at the start waits for the hover throttle learned in flight to be trusted (PX4's filter: about
        2 s of a settled estimate), within the hold's own time limit; True at once with ``--no-hover-learning`` and
        when nothing is being learned (an autopilot that does not stream ATTITUDE_TARGET: no thrust to learn from)."""
        learner = self.hover_learner
        if not self.cfg.learn_hover or learner is None or learner.fusions == 0:
            return True
        return learner.learned() is not None

    def _reread_hover_throttle(self) -> None:
        """After the take-off and the hold at the start, choose the hover throttle again: the one learned in flight
        when trusted (and ``LoopConfig.learn_hover``), else the autopilot's read again (ArduPilot learns
        MOT_THST_HOVER under its own altitude controller) against the file's; map thrust with it from now on."""
        learner = self.hover_learner
        if learner is not None:
            learner.mark_control_start()
        learned = learner.learned() if learner is not None and self.cfg.learn_hover else None
        if learner is not None and self.cfg.learn_hover and learned is None:
            self.event(
                "phase",
                f"hover throttle not learned yet ({learner.fusions} fusions, estimate {learner.ekf.h:.3f} +- "
                f"{learner.ekf.sigma:.3f}, not trusted): flying with the autopilot's or the vehicle file's",
            )
        h, why = choose_hover_throttle(self.mgr.flavour, self.mgr.read_hover_throttle(), self.vehicle, learned)
        if why is not None and learned is not None:
            self.mgr.warnings.append(why)
            self.event("hover_throttle", why)
        v = self.vehicle
        if learner is not None and v.mass_load > 0.0:
            learner.watch_load(v.mass_load / (v.mass_vehicle + v.mass_load))
        before = self.mapper.autopilot.hover_thrust_norm
        if h is None or h == before:
            return
        self.mapper.set_autopilot(replace(self.mapper.autopilot, hover_thrust_norm=h))
        how = f"learned in flight ({learned[1]:.3f} 1-sigma)" if learned is not None else "re-read in flight"
        self.event("phase", f"hover throttle {how}: {h:.3f} (before the take-off: {before})")


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
