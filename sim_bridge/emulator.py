"""The emulator's clock: the plant stepped at 1 kHz with the autopilot's inner loops, paced in real time or in
lockstep with the offboard controller's setpoints.

Real time (``realtime``): simulation time follows the wall clock; the loop steps the plant up to "now", sends
the telemetry that came due, and waits for datagrams until the next step is due.

Lockstep (``lockstep``): the plant advances exactly ``period`` seconds of simulation time for every setpoint
received (SET_ATTITUDE_TARGET, SET_POSITION_TARGET_LOCAL_NED, SET_ACTUATOR_CONTROL_TARGET addressed to us):

1. the setpoint is applied (if the mode uses it),
2. the plant steps ``period`` (``round(period / plant_dt)`` steps), sending every telemetry message that comes
   due during those steps with its own simulation timestamp,
3. a SYSTEM_TIME message marks the end of the step (its ``time_boot_ms`` is the new simulation time),
4. the emulator waits for the next setpoint.

So a controller reads telemetry up to the SYSTEM_TIME marker, computes, and sends its next setpoint. When no
setpoint has arrived for ``grace`` seconds of wall time, the emulator free-runs in real time (so arming, mode
changes and clients that do not stream still work) until the next setpoint arrives. With link faults enabled, a
setpoint dropped or delayed by the injected faults still advances the clock (the handshake is the simulation's
clock, not part of the emulated link).

Disturbances (``disturbance``, e.g. ``sim_bridge.plant.disturbances.RandomDisturbance``): the environment's external
inputs. Before every plant step at simulation time ``t`` the plant input slots 4-12 (force on the vehicle, force on
the load, external torque; ``sim_bridge.plant.dynamics``) are set to ``disturbance(t - origin)``, held over the step.
``origin`` is 0 (``"boot"``), the first OFFBOARD / GUIDED / GUIDED_NOGPS entry (``"offboard"``), or the time a
harness running the emulator in its process sets with :meth:`Emulator.set_disturbance_origin` (``"harness"``:
e.g. ``slung demo``, which knows when its scenario's reference started); no disturbance before the origin is
known. :meth:`Emulator.set_disturbance_origin` also overrides the other two. Slots 4-12 are 0 without a
disturbance.

Drag: a vehicle with ``linear_drag`` > 0 (``estimators.model.vehicle.Vehicle``; PX4 SIH's SIH_KDV, 1 N/(m/s) on its
1 kg quadrotor) also feels ``-linear_drag * v`` (world frame, still air), added to the force on the vehicle (slots
4-6) before every step and held over it, so that its accelerometer senses it as SIH's does; the disturbance log
(``input_log``) keeps the disturbance alone. A vehicle with ``angular_drag`` > 0 (SIH_KDW, 0.025 N m/(rad/s)) feels
``-angular_drag * w`` on its body rates, added to the external torque (slots 10-12) the same way.

Ground: the vehicle rests on the ground plane z = 0 (model NWU) on landing gear tall enough for the load to hang
free; while on the ground and the collective thrust does not exceed the total weight the state is held at rest.
A descent through z = 0 is a touchdown: the vehicle is put at rest there, level, with the cable hanging.
"""

from __future__ import annotations

import logging
import math
import select
import time
from collections.abc import Callable, Sequence
from typing import Any

from estimators.model.vehicle import Vehicle
from sim_bridge.autopilot import SETPOINT_IDS, Autopilot
from sim_bridge.emulator_api import EmulatorTruth
from sim_bridge.plant.dynamics import apply_drag, make_state, plant_params, rk4_step, tension
from sim_bridge.protocol.link import Link

log = logging.getLogger(__name__)


def _has_setpoint_frame(data: bytes) -> int:
    """Count frames in a datagram whose header says setpoint (used for lockstep when faults delay packets)."""
    n = 0
    i = 0
    L = len(data)
    while i < L:
        b = data[i]
        if b == 0xFD and i + 10 <= L:
            mid = data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)
            if mid in SETPOINT_IDS:
                n += 1
            i += 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
        elif b == 0xFE and i + 6 <= L:
            if data[i + 5] in SETPOINT_IDS:
                n += 1
            i += 8 + data[i + 1]
        else:
            i += 1
    return n


class Emulator:
    """Plant + autopilot + link, driven by the real-time or the lockstep clock."""

    def __init__(
        self,
        autopilot: Autopilot,
        link: Link,
        vehicle: Vehicle,
        *,
        clock: str = "realtime",
        period: float = 0.01,
        grace: float = 0.05,
        plant_dt: float = 0.001,
        attitude_model: str = "rigid",
        disturbance: Callable[[float], Sequence[float]] | None = None,
        disturbance_origin: str = "offboard",
    ) -> None:
        if disturbance_origin not in ("boot", "offboard", "harness"):
            raise ValueError(f"disturbance_origin must be 'boot', 'offboard' or 'harness', got {disturbance_origin!r}")
        if clock not in ("realtime", "lockstep"):
            raise ValueError(f"clock must be 'realtime' or 'lockstep', got {clock!r}")
        self.ap = autopilot
        self.link = link
        self.p = plant_params(vehicle, attitude_model)
        self.clock = clock
        self.h = plant_dt
        self.h_us = round(plant_dt * 1e6)
        self.steps_per_period = max(1, round(period / plant_dt))
        self.grace = grace
        self.x = make_state()
        self.u = [0.0] * 13
        self.on_ground = True
        self.t_us = 0
        self.weight = vehicle.total_mass * vehicle.gravity
        self._stop = False
        self.steps = 0
        self.lockstep_steps = 0
        self.nonfinite_resets = 0
        self.wall_start = 0.0
        self.wall_end = 0.0
        autopilot.lockstep_marker = clock == "lockstep"
        self.disturbance = disturbance
        self.disturbance_origin = disturbance_origin
        #: linear drag on the vehicle, N per m/s (module docstring), and the disturbance's force on the vehicle alone
        self.drag = vehicle.linear_drag
        self.dist_force = (0.0, 0.0, 0.0)
        #: angular damping, N m per rad/s of body rate, and the disturbance's torque alone (body, model frame)
        self.angular_drag = vehicle.angular_drag
        self.dist_torque = (0.0, 0.0, 0.0)
        #: simulation time (µs) the disturbance's clock starts from (None: not known yet)
        self.dist_origin_us: int | None = 0 if disturbance_origin == "boot" else None
        #: largest |disturbance| seen per channel: force on the vehicle x, y, z (N world), yaw torque (N m)
        self.dist_max_abs = [0.0, 0.0, 0.0, 0.0]
        #: when set to a list, every plant step appends (t_us at the step's start, u[4:13]) (tests, analysis)
        self.input_log: list[tuple[int, tuple[float, ...]]] | None = None

    def set_disturbance_origin(self, t_s: float) -> None:
        """Start the disturbance's clock at simulation time ``t_s`` (s): the plant then sees ``d(t - t_s)``."""
        if not math.isfinite(t_s) or t_s < 0.0:
            raise ValueError(f"disturbance origin must be a finite time >= 0 s, got {t_s!r}")
        self.dist_origin_us = round(t_s * 1e6)

    def _apply_disturbance(self, u: list[float]) -> None:
        """Plant input slots 4-12 from the disturbance at the current step's start (module docstring)."""
        o = self.dist_origin_us
        if o is None:
            o = self.ap.offboard_entry_us if self.disturbance_origin == "offboard" else None
            if o is None:
                return
            self.dist_origin_us = o
        d = self.disturbance(max(self.t_us - o, 0) * 1e-6)  # type: ignore[misc]
        u[4], u[5], u[6], u[7], u[8], u[9], u[10], u[11], u[12] = d
        self.dist_force = (u[4], u[5], u[6])
        self.dist_torque = (u[10], u[11], u[12])
        m = self.dist_max_abs
        for i, j in ((0, 4), (1, 5), (2, 6), (3, 12)):
            a = abs(u[j])
            if a > m[i]:
                m[i] = a

    def truth(self) -> EmulatorTruth:
        """The plant as it is now (a typed copy; model frame, SI; ``sim_bridge.emulator_api.EmulatorTruth``)."""
        x = tuple(self.x)
        u = list(self.u)
        return EmulatorTruth(
            time_s=self.t_us * 1e-6,
            position_m=(x[0], x[1], x[2]),
            velocity_m_s=(x[3], x[4], x[5]),
            euler_rad=(x[6], x[7], x[8]),
            euler_rate_rad_s=(x[9], x[10], x[11]),
            cable_direction=(x[12], x[13], x[14]),
            cable_rate_1_s=(x[15], x[16], x[17]),
            thrust_n=u[0],
            torque_n_m=(u[1], u[2], u[3]),
            disturbance=tuple(u[4:13]),
            tension_n=float(tension(list(x), u, self.p)),
            on_ground=self.on_ground,
            state=x,
        )

    def disturbance_at(self, t_s: float) -> tuple[float, ...]:
        """The disturbance inputs (plant slots 4-12) the plant receives at simulation time ``t_s`` (zeros without
        one or before its clock starts)."""
        o = self.dist_origin_us
        if self.disturbance is None or o is None:
            return (0.0,) * 9
        return tuple(float(v) for v in self.disturbance(max(round(t_s * 1e6) - o, 0) * 1e-6))

    def stop(self) -> None:
        """Ask the loop to end (thread-safe enough: a flag read once per iteration)."""
        self._stop = True

    # ---------------------------------------------------------------- plant
    def step(self, n: int) -> None:
        """Advance the plant ``n`` steps with the inner loops; telemetry that comes due is sent."""
        ap = self.ap
        link = self.link
        faulty = link._faulty
        x, u, p, h = self.x, self.u, self.p, self.h
        weight = self.weight
        dist = self.disturbance
        log = self.input_log
        drag = self.drag
        kdw = self.angular_drag
        for _ in range(n):
            thrust, tx, ty, tz = ap.control(x, self.on_ground)
            u[0], u[1], u[2], u[3] = thrust, tx, ty, tz
            if dist is not None:
                self._apply_disturbance(u)
            if log is not None:  # the disturbance alone (slots 4-6 also carry the drag of the last step)
                log.append((self.t_us, (*self.dist_force, *u[7:13])))
            if drag > 0.0 or kdw > 0.0:  # still air, SIH's drag and angular damping at the step's start
                apply_drag(u, x, self.dist_force, self.dist_torque, drag, kdw)
            if self.on_ground:
                if thrust > weight * 1.0001:
                    self.on_ground = False
                    x = rk4_step(x, u, p, h)
            else:
                x = rk4_step(x, u, p, h)
                if x[2] < 0.0:
                    x = self._touchdown(x)
            s = x[0] + x[3] + x[6] + x[9] + x[12] + x[15] + x[2] + x[5] + x[8] + x[11]
            if s - s != 0.0:
                x = self._nonfinite()
            self.t_us += self.h_us
            if faulty:
                link.now = self.t_us * 1e-6
                link.flush_due()
                for data, ep, addr in link.due_incoming():
                    ap.handle_datagram(data, ep, addr)
            ap.after_step(self.t_us, x, u, self.on_ground)
        self.x = x
        self.steps += n

    def _touchdown(self, x: list[float]) -> list[float]:
        self.on_ground = True
        return make_state((x[0], x[1], 0.0), euler=(0.0, 0.0, x[8]))

    def _nonfinite(self) -> list[float]:
        self.nonfinite_resets += 1
        self.on_ground = True
        self.ap.armed = False
        self.ap.statustext(0, "EMERGENCY: plant state not finite, reset")
        return make_state()

    # ---------------------------------------------------------------- input
    def _receive(self) -> int:
        """Read and handle all waiting datagrams; returns the number of setpoints accepted."""
        link = self.link
        link.now = self.t_us * 1e-6
        n = 0
        for data, ep, addr in link.poll():
            n += self.ap.handle_datagram(data, ep, addr)
        if link._faulty:
            for data, ep, addr in link.due_incoming():
                n += self.ap.handle_datagram(data, ep, addr)
        return n

    def _receive_faulty_lockstep(self) -> int:
        """Lockstep with faults: count setpoint frames at reception, even if delayed or dropped."""
        link = self.link
        link.now = self.t_us * 1e-6
        received: list[bytes] = []
        now = link.poll(received.append)
        for data, ep, addr in (*now, *link.due_incoming()):
            self.ap.handle_datagram(data, ep, addr)
        return sum(_has_setpoint_frame(data) for data in received)

    # ---------------------------------------------------------------- loop
    def run(self, duration: float | None = None) -> None:
        """Run until ``duration`` seconds of simulation time (None: until :meth:`stop`)."""
        end_us = None if duration is None else int(duration * 1e6)
        socks = self.link.fileno_list()
        self.wall_start = time.monotonic()
        # realtime anchor: wall time that corresponds to sim time t_anchor
        anchor_wall = self.wall_start
        anchor_t = 0
        streaming = False
        last_sp_wall = 0.0
        lockstep = self.clock == "lockstep"
        faulty = self.link._faulty
        h_us = self.h_us
        try:
            while not self._stop and (end_us is None or self.t_us < end_us):
                if lockstep and streaming:
                    wait = self.grace - (time.monotonic() - last_sp_wall)
                    if wait <= 0.0:
                        streaming = False
                        anchor_wall, anchor_t = time.monotonic(), self.t_us
                        continue
                    r, _, _ = select.select(socks, [], [], min(wait, 0.1))  # 0.1: notice stop() soon
                    if not r:
                        continue
                    n = self._receive_faulty_lockstep() if faulty else self._receive()
                    if n:
                        last_sp_wall = time.monotonic()
                        self._lockstep_advance(n, end_us)
                    continue
                # real-time pacing (realtime clock, or lockstep free-run)
                now = time.monotonic()
                target = anchor_t + int((now - anchor_wall) * 1e6)
                behind = (target - self.t_us) // h_us
                if behind > 0:
                    if end_us is not None:
                        behind = min(behind, (end_us - self.t_us + h_us - 1) // h_us)
                    self.step(min(behind, 200))
                    if behind > 2000:  # we cannot keep up: let the clock slip rather than spiral
                        anchor_wall, anchor_t = now, self.t_us
                next_wall = anchor_wall + (self.t_us + h_us - anchor_t) * 1e-6
                wait = max(0.0, min(next_wall - time.monotonic(), 0.002))
                r, _, _ = select.select(socks, [], [], wait)
                if r:
                    n = self._receive_faulty_lockstep() if (faulty and lockstep) else self._receive()
                    if lockstep and n:
                        streaming = True
                        last_sp_wall = time.monotonic()
                        self.ap.rephase()
                        self._lockstep_advance(n, end_us)
                elif faulty:
                    self.link.now = self.t_us * 1e-6
        finally:
            self.wall_end = time.monotonic()

    def _lockstep_advance(self, n: int, end_us: int | None) -> None:
        steps = n * self.steps_per_period
        if end_us is not None:
            steps = min(steps, max(0, (end_us - self.t_us) // self.h_us))
        self.step(steps)
        self.lockstep_steps += n
        self.ap.send_step_marker()

    def summary(self) -> dict[str, Any]:
        """Clock figures for the final report."""
        wall = max(self.wall_end - self.wall_start, 1e-9)
        return {
            "clock": self.clock,
            "sim_time_s": self.t_us / 1e6,
            "wall_time_s": wall,
            "realtime_factor": (self.t_us / 1e6) / wall,
            "plant_steps": self.steps,
            "lockstep_handshakes": self.lockstep_steps,
            "nonfinite_resets": self.nonfinite_resets,
            "on_ground": self.on_ground,
            "altitude_m": self.x[2],
            "disturbance": None
            if self.disturbance is None
            else {
                "origin": self.disturbance_origin,
                "origin_s": None if self.dist_origin_us is None else self.dist_origin_us / 1e6,
                "max_abs_force_xyz_n": self.dist_max_abs[:3],
                "max_abs_torque_yaw_nm": self.dist_max_abs[3],
            },
        }
