"""The estimation-only replay (``offboard.logs.replay``): where a log holds no offboard flight, the estimator ticks on
a fixed grid of vehicle time (``rate_hz``), driven by the newest sample time seen; the collective is the
accelerometer's, low-passed. Model frame, SI units, radians.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from typing import Any

from estimators.model.frames import STANDARD_GRAVITY
from estimators.model.measurements import Attitude, Imu, LoadAngle, PositionVelocity
from estimators.model.vehicle import Vehicle
from offboard.logs.log_inventory import (
    Event,
    Segment,
    clock_jump,
)
from offboard.logs.replay_health import HealthMonitor
from offboard.logs.replay_records import EST_COLUMNS, initial_guess

#: weight of a new IMU sample in the low-pass of the measured collective (commands unknown, estimation only)
ACC_LOWPASS = 0.05


def replay_grid(
    events: list[Event],
    estimator: Any,
    vehicle: Vehicle,
    rate: float,
    t_from: float,
    t_to: float,
    load_sensor: bool,
    output: str,
    progress: Callable[[float], None] | None,
    segments: list[Segment],
) -> tuple[list[tuple[float, ...]], dict[str, Any]]:
    """Estimation only, on a fixed grid of vehicle time driven by the newest sample time (see module docstring).

    The filter has no ground contact in its model, so it runs only over the log's airborne segments
    (``offboard.logs.log_inventory.flight_segments``: armed and off the ground), one fresh start per segment, each
    initialized from the latest telemetry as the live loop does; a reboot or clock step ends a segment. Every tick
    is checked (``offboard.logs.replay_health.HealthMonitor``); a diverged tick is recorded as unusable (NaN estimate),
    reported with its time and reason, and the filter restarts from the autopilot's state.

    The commands the vehicle flew are not in the log: the filter is told the collective the accelerometer measured
    (hover thrust scaled by the low-passed specific force along body z over g, within 0.3..2) and no torque. (Raising
    the process noise of the command-driven states 10-100x was tried: it halved the refusals on the real logs but
    made the sensorless swing 1.5-2x worse on a near-hover flight; not kept.)"""
    nan = math.nan
    nsp = 8 if output == "attitude" else 4
    tail = (nan,) * (8 + 2 * nsp)
    rows: list[tuple[float, ...]] = []
    period = 1.0 / rate
    hover_thrust = vehicle.hover_thrust
    zero3 = (0.0, 0.0, 0.0)
    nan_est = (nan,) * len(EST_COLUMNS)
    health = HealthMonitor(vehicle.cable_length)
    by_epoch: dict[int, list[tuple[float, float, int]]] = {}
    for i, sg in enumerate(segments):
        by_epoch.setdefault(sg.epoch, []).append((sg.t0, sg.t1, i))
    starts_of = {ep: [s[0] for s in lst] for ep, lst in by_epoch.items()}
    epoch = 0
    t_att = -math.inf
    running = False
    cur_seg = -1
    last_att: Attitude | None = None
    last_pv: PositionVelocity | None = None
    last_ld: LoadAngle | None = None
    vnow = -math.inf
    next_tick = math.inf
    last_load = (nan, nan)
    last_pos = (nan, nan, nan)
    last_att3 = (nan, nan, nan)
    last_at: tuple[float, ...] = (nan,) * 5
    offboard = nan
    n = len(events)
    resets = 0
    starts = 0
    gated = 0.0
    t_init: float | None = None
    k_tick = 0
    az_lp = STANDARD_GRAVITY
    thrust = hover_thrust
    n_pos = 0

    def start_filter(t0: float) -> None:
        estimator.initialize(t0, initial_guess(vehicle, last_pv, last_att, last_ld if load_sensor else None))
        estimator.push_command(t0, thrust, zero3)
        health.restarted(estimator.stats())

    for idx, e in enumerate(events):
        if progress is not None and idx % 4000 == 0:
            progress(idx / n)
        kind = e.kind
        if kind == "m":
            m = e.payload
            if isinstance(m, Attitude):
                if clock_jump(m.t, t_att) is not None:
                    resets += 1  # a reboot or clock step: a new epoch of vehicle time; start afresh
                    epoch += 1
                    running = False
                    last_pv = last_ld = None
                    vnow = -math.inf
                t_att = m.t
                last_att = m
                last_att3 = (m.phi, m.theta, m.psi)
            elif isinstance(m, PositionVelocity):
                last_pv = m
                last_pos = (m.x, m.y, m.z)
                n_pos += 1
            elif isinstance(m, LoadAngle):
                last_ld = m
                last_load = (m.alpha_x, m.alpha_y)
            elif isinstance(m, Imu):  # the collective the vehicle flew: its low-passed specific force along body z
                az_lp += ACC_LOWPASS * (m.az - az_lp)
                thrust = hover_thrust * min(2.0, max(0.3, az_lp / STANDARD_GRAVITY))
            if m.t < t_from or m.t > t_to:
                continue
            seg = -1
            lst = by_epoch.get(epoch)
            if lst is not None:
                j = bisect.bisect_right(starts_of[epoch], m.t) - 1
                if j >= 0 and m.t <= lst[j][1]:
                    seg = lst[j][2]
            if seg < 0:
                running = False
                continue
            if not running or seg != cur_seg:
                running = False
                if last_att is not None and last_pv is not None and (last_ld is not None or not load_sensor):
                    t0 = max(last_att.t, last_pv.t)
                    start_filter(t0)
                    running = True
                    cur_seg = seg
                    starts += 1
                    t_init = t0 if t_init is None else t_init
                    vnow = t0
                    next_tick = t0 + period
                continue
            if m.t > vnow:
                vnow = m.t
            while next_tick <= vnow:
                est = estimator.estimate(next_tick)
                look = k_tick % 25 == 0
                k_tick += 1
                st = estimator.stats() if look else None
                if st is not None:
                    gated = float(sum(v for k, v in st.items() if k.startswith("gated_") and k != "gated_outliers"))
                why = health.check(next_tick, est, last_pv, st, n_pos)
                if why:
                    health.report(next_tick, why, seg)
                    vals: tuple[float, ...] = nan_est
                else:
                    estimator.push_command(next_tick, thrust, zero3)
                    vals = (*est.fx, *est.fy, *est[2:])
                rows.append(
                    (
                        next_tick,
                        nan,
                        e.lt,
                        0.0,
                        *vals,
                        *last_load,
                        *last_pos,
                        *tail,
                        *last_at,
                        offboard,
                        nan,
                        nan,
                        *last_att3,
                        float(seg),
                        1.0 if why else 0.0,
                        gated,
                        *estimator.sigmas(),
                        *estimator.innovations(),
                    )
                )
                next_tick += period
                if why:  # restart from the autopilot's state, at the newest sample time
                    start_filter(max(last_att.t if last_att else vnow, last_pv.t if last_pv else vnow))
                    next_tick = max(next_tick, vnow + period)
                    break
            estimator.push(m)
        elif kind == "mode":
            offboard = 1.0 if e.payload else 0.0
        elif kind == "at":
            last_at = (*e.payload[0], e.payload[1])
    return rows, {
        "controller_ran": False,
        "t_init": t_init,
        "clock_resets": resets,
        "filter_starts": starts,
        "airborne_gating": True,
        "divergences": health.events,
        "diverged_ticks": health.diverged_ticks,
    }
