"""Which ticks a replay runs (``offboard.logs.replay``): one per logged setpoint, from the live loop's own log
(``timeseries_live.slts``: tick time, reference time, the measurements pushed before the tick) or, without it,
from the setpoints and events of the tlog. Times are the vehicle's (s since boot).
"""

from __future__ import annotations

import bisect
import math
import struct
from typing import Any, NamedTuple

import numpy as np

from offboard.flight.link.setpoints import AttitudeTarget
from offboard.logs.log_inventory import (
    Event,
)
from offboard.logs.replay_records import LiveLogMismatchError, LiveRun

F32 = struct.Struct("<f")


def f32(v: float) -> float:
    """``v`` rounded to float32, as a MAVLink float field carries it."""
    return F32.unpack(F32.pack(v))[0] if math.isfinite(v) and abs(v) < 3.4e38 else v


def sp_fields(sp: Any) -> tuple[float, ...]:
    if isinstance(sp, AttitudeTarget):
        return (*sp.q, sp.roll_rate, sp.pitch_rate, sp.yaw_rate, sp.thrust)
    return tuple(sp)


class ReplayTick(NamedTuple):
    """One controller tick to replay: vehicle time t_v and controller time t_ref (s); n_push: measurements of the
    autopilot's stream pushed since the start index; logged: the logged wire setpoint; lt: its logger time;
    live: row index in the live tick log or -1."""

    t_v: float
    t_ref: float
    n_push: int
    logged: tuple[float, ...]
    lt: float
    live: int


def plan_from_live(
    meas_pos: list[int], sp_events: list[tuple[int, Event]], live: LiveRun, output: str
) -> tuple[int, list[ReplayTick]]:
    """Align the live tick log with the tlog: the first logged setpoint equal (float32) to the live log's first
    one marks tick 0; the estimator was initialized ``n_meas[0]`` measurements before it. Returns the index in the
    measurement stream of the first pushed measurement and the ticks."""
    n = len(live.t_vehicle)
    if n == 0:
        raise LiveLogMismatchError("the live tick log is empty")
    nsp = 8 if output == "attitude" else 4
    want = tuple(f32(float(v)) for v in live.sp[0, :nsp])
    j0 = next((j for j, (_, e) in enumerate(sp_events) if sp_fields(e.payload[0]) == want), None)
    if j0 is None:
        raise LiveLogMismatchError("the live tick log does not match this tlog (its first setpoint is not in the log)")
    if j0 + n > len(sp_events):
        raise LiveLogMismatchError(
            f"the live tick log has {n} ticks but the tlog only {len(sp_events) - j0} setpoints after the first one"
        )
    first_idx = sp_events[j0][0]
    before = bisect.bisect_left(meas_pos, first_idx)
    start = before - int(live.n_meas[0])
    if start < 0:
        raise LiveLogMismatchError("the live tick log counts more measurements than the tlog holds")
    ticks = []
    for k in range(n):
        e = sp_events[j0 + k][1]
        ticks.append(
            ReplayTick(
                float(live.t_vehicle[k]), float(live.t_ref[k]), int(live.n_meas[k]), sp_fields(e.payload[0]), e.lt, k
            )
        )
    return start, ticks


def is_hover(sp: Any) -> bool:
    """Whether a setpoint is the live loop's hover setpoint (level, zero rates / torques): what it streams before
    offboard control starts and after it ends, never a controller output in practice."""
    if isinstance(sp, AttitudeTarget):
        return sp.q[1] == 0.0 and sp.q[2] == 0.0 and sp.roll_rate == 0.0 and sp.pitch_rate == 0.0 and sp.yaw_rate == 0.0
    return sp.roll == 0.0 and sp.pitch == 0.0 and sp.yaw == 0.0


def plan_from_setpoints(
    events: list[Event],
    meas_pos: list[int],
    meas: list[Any],
    sp_events: list[tuple[int, Event]],
    output: str,
    rate_hz: float,
) -> tuple[int, list[ReplayTick]]:
    """Ticks from the logged setpoints alone (no live tick log), following ``offboard.flight.loop.FlightLoop``:

    - the controlled segment is the run of setpoints that are not hover setpoints (:func:`is_hover`), after the
      HEARTBEAT reporting offboard mode when the log has one; the filter is initialized from the telemetry
      logged before its first setpoint;
    - each tick's vehicle time is the newest SYSTEM_TIME marker before its setpoint when the autopilot sends one
      per tick (the lockstep emulator's handshake; a tick without a new marker is the previous tick + 1 /
      ``rate_hz``, as the loop does), else the newest sample time before the first tick plus the setpoint's time
      field (whole ms for SET_ATTITUDE_TARGET, snapped to the tick period when regular);
    - controller time ``t_ref = t_v - t0`` with ``t0`` the newest marker before the first tick (lockstep), else
      the newest sample time before it.

    Exact for lockstep runs of the loop; approximate otherwise (the loop's real-time tick times are not on the
    wire: use its tick log, ``timeseries_live.slts``, for an exact replay)."""
    on_idx = next((i for i, e in enumerate(events) if e.kind == "mode" and e.payload), None)
    cand = [(i, e) for i, e in sp_events if on_idx is None or i > on_idx]
    k0 = next((k for k, (_, e) in enumerate(cand) if not is_hover(e.payload[0])), None)
    if k0 is None:
        return 0, []
    k1 = next((k for k in range(k0, len(cand)) if is_hover(cand[k][1].payload[0])), len(cand))
    sel = cand[k0:k1]
    start = bisect.bisect_left(meas_pos, sel[0][0])  # the filter starts from what was known at the first tick
    t_newest = max((m.t for m in meas[:start]), default=0.0)
    times = [
        e.payload[1].time_boot_ms * 1e-3 if output == "attitude" else e.payload[1].time_usec * 1e-6 for _, e in sel
    ]
    period = 1.0 / rate_hz
    if len(times) > 2:
        d = np.diff(np.asarray(times))
        d = d[d > 0]
        if len(d) and abs(float(np.median(d)) - period) > 0.0011:
            period = float(np.median(d))
    if (
        output == "attitude"
        and period >= 0.002
        and all(abs(t / period - round(t / period)) * period <= 0.0011 for t in times[: min(len(times), 500)])
    ):
        times = [round(t / period) * period for t in times]
    clock_pos = [i for i, e in enumerate(events) if e.kind == "clock"]
    n_clock = sum(1 for i in clock_pos if sel[0][0] <= i <= sel[-1][0]) if clock_pos else 0
    t_vs: list[float] = []
    if n_clock >= 0.9 * (len(sel) - 1):
        # lockstep: the loop takes t0 from the newest marker when control starts; the emulator only advances on a
        # setpoint, so the first tick finds no new marker and runs at the predicted t0 + period
        c0 = bisect.bisect_left(clock_pos, sel[0][0]) - 1
        t0 = t_newest if c0 < 0 else events[clock_pos[c0]].payload
        last_c = c0
        for i, _ in sel:
            c = bisect.bisect_left(clock_pos, i) - 1
            if c == last_c or c < 0:
                t_vs.append(t_vs[-1] + period if t_vs else t0 + period)
            else:
                t_vs.append(events[clock_pos[c]].payload)
            last_c = c
    else:
        t0 = t_newest
        t_vs = [t_newest + t for t in times]
    ticks = []
    last = -math.inf
    for (i, e), t_v in zip(sel, t_vs):
        if not t_v >= last:  # out of order (the loop may tick twice at one time, never backwards)
            continue
        last = t_v
        n_push = bisect.bisect_left(meas_pos, i) - start
        ticks.append(ReplayTick(t_v, t_v - t0, n_push, sp_fields(e.payload[0]), e.lt, -1))
    return start, ticks
