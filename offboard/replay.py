"""tlog -> the live loop's measurements -> the same estimator and controller: what a flight log contains, what the
filter makes of it, and what the controller would have sent.

Two passes over memory, one over the file:

1. **Read and inventory** (``offboard.log_inventory``: :func:`scan`, :func:`inventory`): every packet of the tlog
   (``offboard.tlog``) counted per system and type, the autopilot identified, telemetry decoded by the live
   link's own decoder into measurement records on the vehicle's own time, setpoints and events kept in log
   order.
2. **Replay** (:func:`replay`): the measurements of the autopilot's system are pushed into the estimator
   (``estimators.make_estimator``) in the order the logger received them. Ticks:

   - where the log holds an offboard flight (setpoints sent to the autopilot), one tick per logged setpoint:
     the estimator sees exactly the measurements logged before it, the controller (``offboard.smc.step``) and
     the command mapping (``offboard.command_mapping``) run, and the recomputed setpoint is compared with the
     logged one. The controller needs the reference the flight used (scenario name and its start time, from
     the run's ``metrics.json`` beside the tlog or from the command line); without it only the estimator runs.
   - elsewhere the estimator ticks on a fixed grid (``rate_hz``) of vehicle time, driven by the newest sample
     time seen (a loop with no latency): estimation only.

Everything is in the model frame (world NWU z up, body FLU), SI units and radians; time ``t`` is the vehicle's
time since boot (s). Output: :class:`ReplayResult` (a table with one row per tick, ``metrics``), written by
:func:`write_outputs` as ``timeseries.csv``, ``metrics.json`` and figures.
"""

from __future__ import annotations

import bisect
import contextlib
import gc
import itertools
import math
import operator
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from estimators.control_state import ControlState
from estimators.measurements import Attitude, LoadAngle, PositionVelocity
from estimators.vehicle import Vehicle
from offboard.link.setpoints import ActuatorTarget, AttitudeTarget
from offboard.log_inventory import (
    REBOOT_JUMP_S,
    Event,
    Scan,
    SystemInfo,
    inventory,
    is_offboard_mode,
    replayable,
    vehicle_time_of,
)
from offboard.log_inventory import scan as _scan


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Pause the cyclic garbage collector (restored on exit): both passes allocate a few acyclic objects per packet
    or tick, freed by reference counting, and the collector's repeated passes over the growing event list and
    table cost 10-20 % of the pass."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def scan(messages: Iterable[tuple[float, Any]]) -> Scan:
    """Pass 1: :func:`offboard.log_inventory.scan`, with the cyclic garbage collector paused."""
    with _collector_paused():
        return _scan(messages)

# ---------------------------------------------------------------------------------------------------------------
# pass 2: replay


@dataclass(frozen=True)
class ReferenceSpec:
    """The reference a logged flight used: the scenario's name (or a trajectory file). ``start``: the vehicle time
    (s) at which the reference's t = 0 fell, NaN = at the first replayed tick (ignored with the live run's tick log,
    whose controller time ``t_ref`` is used). ``origin``: the horizontal shift (m, world NWU) the live loop added
    to the reference's F_x, F_y, or None to recompute it as the loop does (vehicle position at the start minus
    the reference's start)."""

    scenario: str
    start: float = math.nan
    origin: tuple[float, float] | None = None
    trajectory: str | None = None

    def build(self) -> Any:
        """The reference object (``offboard.reference``): the named scenario's or the trajectory file's."""
        if self.trajectory is not None:
            from offboard.reference import load_trajectory_file

            return load_trajectory_file(self.trajectory)
        from offboard.scenarios import make_scenario

        return make_scenario(self.scenario).reference


class LiveLogMismatchError(ValueError):
    """The live tick log given to the replay does not belong to the tlog."""


@dataclass(frozen=True)
class LiveRun:
    """The live loop's own per-tick log (``timeseries_live.csv`` of ``slung fly`` / ``slung demo``; columns of
    ``offboard.loop.LIVE_COLUMNS``): tick vehicle time ``t_vehicle`` (s), controller time ``t_ref`` (s), cumulative
    number of measurements pushed to the estimator ``n_meas``, the estimate the controller used (N x 24, order
    :data:`EST_COLUMNS`) and the setpoint's wire fields (N x 8 attitude / N x 4 actuator, full precision)."""

    t_vehicle: np.ndarray
    t_ref: np.ndarray
    n_meas: np.ndarray
    est: np.ndarray
    sp: np.ndarray


LIVE_EST_NAMES = ("fx0", "fx1", "fx2", "fx3", "fx4", "fx5", "fy0", "fy1", "fy2", "fy3", "fy4", "fy5", "z", "z_rate",
                  "phi", "theta", "psi", "phi_rate", "theta_rate", "psi_rate", "alpha_x", "alpha_y",
                  "alpha_x_rate", "alpha_y_rate")


def load_live_table(path: Any) -> LiveRun | None:
    """The :class:`LiveRun` in the CSV at ``path``, or None when the file is missing, lacks a needed column or has
    a row of another width. Only the needed columns are converted (``float`` of each field: the same doubles as
    ``np.loadtxt``, in a third of its time on the loop's ~70 columns)."""
    try:
        with open(path, encoding="utf-8") as fh:
            header = fh.readline().strip().split(",")
            lines = fh.read().split("\n")
    except (OSError, ValueError):
        return None
    idx = {n: i for i, n in enumerate(header)}
    need = ["t_vehicle", "t_ref", "n_meas", *("est_" + n for n in LIVE_EST_NAMES), *(f"sp{i}" for i in range(4))]
    if any(n not in idx for n in need):
        return None
    sp_cols = [idx[f"sp{i}"] for i in range(8) if f"sp{i}" in idx]
    cols = [idx["t_vehicle"], idx["t_ref"], idx["n_meas"], *(idx["est_" + n] for n in LIVE_EST_NAMES), *sp_cols]
    pick = operator.itemgetter(*cols)
    width = len(header)
    values: list[float] = []
    n = 0
    try:
        for line in lines:
            if not line.strip():
                continue
            fields = line.split(",")
            if len(fields) != width:
                return None
            values.extend(map(float, pick(fields)))
            n += 1
    except ValueError:
        return None
    data = np.array(values, dtype=float).reshape(n, len(cols))
    ne = len(LIVE_EST_NAMES)
    sp = data[:, 3 + ne:]
    if sp.shape[1] >= 8 and np.all(np.isnan(sp[:, 4:8])):
        sp = sp[:, :4]
    return LiveRun(data[:, 0], data[:, 1], data[:, 2].astype(int), data[:, 3:3 + ne], sp)


@dataclass(frozen=True)
class ReplayConfig:
    """How to replay.

    vehicle: the controller's nominal vehicle; t_from / t_to: vehicle-time window (s, since boot) or None;
    rate_hz: tick rate where no setpoints are logged (and the estimator's step when the log does not say);
    estimator: estimator kind; load_sensor: None = use one when the log has it; delay_s: the estimator's fusion
    horizon (s); reference: see :class:`ReferenceSpec` (None: no controller); switching / epsilon: the
    controller's switching function; output / mask: None = from the logged setpoints; mapping: extra
    ``MappingConfig`` fields (limits); autopilot: ``AutopilotModel`` fields (flavour, attitude_p, rate_bandwidth,
    hover_thrust_norm, angle_boost; flavour defaults to the HEARTBEAT's); live: the live run's tick log, for an
    exact replay; estimate_only: run the estimator on the grid over the whole log even where it holds an
    offboard flight (no controller).
    """

    vehicle: Vehicle = field(default_factory=Vehicle)
    t_from: float | None = None
    t_to: float | None = None
    rate_hz: float = 250.0
    estimator: str = "kf"
    load_sensor: bool | None = None
    delay_s: float = 0.012
    reference: ReferenceSpec | None = None
    switching: str = "smooth"
    epsilon: float = 1.0
    output: str | None = None
    mask: str | None = None
    mapping: dict[str, Any] | None = None
    autopilot: dict[str, Any] | None = None
    live: LiveRun | None = None
    estimate_only: bool = False


EST_COLUMNS = (
    "Fx", "Fx_d1", "Fx_d2", "Fx_d3", "Fx_d4", "Fx_d5", "Fy", "Fy_d1", "Fy_d2", "Fy_d3", "Fy_d4", "Fy_d5",
    "z", "z_rate", "phi", "theta", "psi", "phi_rate", "theta_rate", "psi_rate",
    "alpha_x", "alpha_y", "alpha_x_rate", "alpha_y_rate",
)
SP_ATT = ("q_w", "q_x", "q_y", "q_z", "roll_rate", "pitch_rate", "yaw_rate", "thrust")
SP_ACT = ("roll", "pitch", "yaw", "thrust")


def columns_for(output: str) -> tuple[str, ...]:
    """The time-series columns for setpoint kind ``output`` ("attitude" or "actuator")."""
    sp = SP_ATT if output == "attitude" else SP_ACT
    return (
        "t", "t_ref", "logger_t", "tick_source", *EST_COLUMNS, "meas_alpha_x", "meas_alpha_y",
        "pos_x", "pos_y", "pos_z",
        "Fx_ref", "Fy_ref", "z_ref", "psi_ref", "cmd_thrust", "cmd_tau_phi", "cmd_tau_theta", "cmd_tau_psi",
        *("sp_" + c for c in sp), *("log_" + c for c in sp), "ap_q_w", "ap_q_x", "ap_q_y", "ap_q_z", "ap_thrust",
        "offboard", "live_est_diff", "live_sp_diff",
    )


@dataclass
class ReplayResult:
    """The replayed run: ``data[k, col[name]]`` per tick, the column names and the metrics dictionary."""

    data: np.ndarray
    columns: tuple[str, ...]
    metrics: dict[str, Any]
    output: str

    def column(self, name: str) -> np.ndarray:
        """One column over the ticks."""
        return self.data[:, self.columns.index(name)]


def initial_guess(vehicle: Vehicle, pv: PositionVelocity | None, att: Attitude | None,
                  load: LoadAngle | None) -> ControlState:
    """The estimator's prior as the live loop builds it: :func:`offboard.loop.initial_guess` (position and
    velocity, attitude, swing from the cable-angle sensor, 0 without one; every rate not measured is 0)."""
    from offboard.loop import initial_guess as live_initial_guess

    return live_initial_guess(vehicle, att, pv, load)


_F32 = struct.Struct("<f")


def _f32(v: float) -> float:
    """``v`` rounded to float32, as a MAVLink float field carries it."""
    return _F32.unpack(_F32.pack(v))[0] if math.isfinite(v) and abs(v) < 3.4e38 else v


def _sp_fields(sp: Any) -> tuple[float, ...]:
    if isinstance(sp, AttitudeTarget):
        return (*sp.q, sp.roll_rate, sp.pitch_rate, sp.yaw_rate, sp.thrust)
    return tuple(sp)


class _Tick(NamedTuple):
    """One controller tick to replay: vehicle time t_v and controller time t_ref (s); n_push: measurements of the
    autopilot's stream pushed since the start index; logged: the logged wire setpoint; lt: its logger time;
    live: row index in the live tick log or -1."""

    t_v: float
    t_ref: float
    n_push: int
    logged: tuple[float, ...]
    lt: float
    live: int


def _plan_from_live(meas_pos: list[int], sp_events: list[tuple[int, Event]], live: LiveRun,
                    output: str) -> tuple[int, list[_Tick]]:
    """Align the live tick log with the tlog: the first logged setpoint equal (float32) to the live log's first
    one marks tick 0; the estimator was initialized ``n_meas[0]`` measurements before it. Returns the index in the
    measurement stream of the first pushed measurement and the ticks."""
    n = len(live.t_vehicle)
    if n == 0:
        raise LiveLogMismatchError("the live tick log is empty")
    nsp = 8 if output == "attitude" else 4
    want = tuple(_f32(float(v)) for v in live.sp[0, :nsp])
    j0 = next((j for j, (_, e) in enumerate(sp_events) if _sp_fields(e.payload[0]) == want), None)
    if j0 is None:
        raise LiveLogMismatchError("the live tick log does not match this tlog (its first setpoint is not in the log)")
    if j0 + n > len(sp_events):
        raise LiveLogMismatchError(f"the live tick log has {n} ticks but the tlog only {len(sp_events) - j0} "
                                   "setpoints after the first one")
    first_idx = sp_events[j0][0]
    before = bisect.bisect_left(meas_pos, first_idx)
    start = before - int(live.n_meas[0])
    if start < 0:
        raise LiveLogMismatchError("the live tick log counts more measurements than the tlog holds")
    ticks = []
    for k in range(n):
        e = sp_events[j0 + k][1]
        ticks.append(_Tick(float(live.t_vehicle[k]), float(live.t_ref[k]), int(live.n_meas[k]),
                           _sp_fields(e.payload[0]), e.lt, k))
    return start, ticks


def _is_hover(sp: Any) -> bool:
    """Whether a setpoint is the live loop's hover setpoint (level, zero rates / torques): what it streams before
    offboard control starts and after it ends, never a controller output in practice."""
    if isinstance(sp, AttitudeTarget):
        return sp.q[1] == 0.0 and sp.q[2] == 0.0 and sp.roll_rate == 0.0 and sp.pitch_rate == 0.0 \
            and sp.yaw_rate == 0.0
    return sp.roll == 0.0 and sp.pitch == 0.0 and sp.yaw == 0.0


def _plan_from_setpoints(events: list[Event], meas_pos: list[int], meas: list[Any],
                         sp_events: list[tuple[int, Event]], output: str, rate_hz: float) -> tuple[int, list[_Tick]]:
    """Ticks from the logged setpoints alone (no live tick log), following ``offboard.loop.FlightLoop``:

    - the controlled segment is the run of setpoints that are not hover setpoints (:func:`_is_hover`), after the
      HEARTBEAT reporting offboard mode when the log has one; the filter is initialized from the telemetry
      logged before its first setpoint;
    - each tick's vehicle time is the newest SYSTEM_TIME marker before its setpoint when the autopilot sends one
      per tick (the lockstep emulator's handshake; a tick without a new marker is the previous tick + 1 /
      ``rate_hz``, as the loop does), else the newest sample time before the first tick plus the setpoint's time
      field (whole ms for SET_ATTITUDE_TARGET, snapped to the tick period when regular);
    - controller time ``t_ref = t_v - t0`` with ``t0`` the newest marker before the first tick (lockstep), else
      the newest sample time before it.

    Exact for lockstep runs of the loop; approximate otherwise (the loop's real-time tick times are not on the
    wire: use its tick log, ``timeseries_live.csv``, for an exact replay)."""
    on_idx = next((i for i, e in enumerate(events) if e.kind == "mode" and e.payload), None)
    cand = [(i, e) for i, e in sp_events if on_idx is None or i > on_idx]
    k0 = next((k for k, (_, e) in enumerate(cand) if not _is_hover(e.payload[0])), None)
    if k0 is None:
        return 0, []
    k1 = next((k for k in range(k0, len(cand)) if _is_hover(cand[k][1].payload[0])), len(cand))
    sel = cand[k0:k1]
    start = bisect.bisect_left(meas_pos, sel[0][0])  # the filter starts from what was known at the first tick
    t_newest = max((m.t for m in meas[:start]), default=0.0)
    times = [e.payload[1].time_boot_ms * 1e-3 if output == "attitude" else e.payload[1].time_usec * 1e-6
             for _, e in sel]
    period = 1.0 / rate_hz
    if len(times) > 2:
        d = np.diff(np.asarray(times))
        d = d[d > 0]
        if len(d) and abs(float(np.median(d)) - period) > 0.0011:
            period = float(np.median(d))
    if output == "attitude" and period >= 0.002 and all(
            abs(t / period - round(t / period)) * period <= 0.0011 for t in times[: min(len(times), 500)]):
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
        ticks.append(_Tick(t_v, t_v - t0, n_push, _sp_fields(e.payload[0]), e.lt, -1))
    return start, ticks


def _find_start(events: list[Event], meas_pos: list[int], meas: list[Any], start: int, ticks: list[_Tick],
                config: ReplayConfig, output: str, load_sensor: bool, make_estimator: Callable[..., Any],
                n_check: int = 8, memo: dict[str, Any] | None = None) -> tuple[int, list[_Tick], str]:
    """Where did the live loop initialize its filter? Without its tick log the tlog does not say: the loop may
    have read a batch of telemetry between initializing and its first tick. Candidates, most likely first: right
    before the first tick, right after each of the last three SYSTEM_TIME markers before it, then 1..8
    measurements earlier. The first candidate whose replay reproduces the first ``n_check`` logged setpoints
    exactly (float32) is taken; otherwise the first one. Returns (start, ticks, how it was chosen)."""
    first = ticks[0]
    before0 = start + first.n_push
    clock_pos = [i for i, e in enumerate(events) if e.kind == "clock"]
    first_ev = meas_pos[before0 - 1] + 1 if before0 > 0 else 0
    c0 = bisect.bisect_right(clock_pos, first_ev) - 1
    cands = [before0]
    for c in range(c0, max(c0 - 3, -1), -1):
        cands.append(bisect.bisect_left(meas_pos, clock_pos[c]))
    cands += [before0 - j for j in range(1, 9)]
    seen: set[int] = set()
    for cand in cands:
        if cand < 1 or cand > before0 or cand in seen:
            continue
        seen.add(cand)
        trial = [tk._replace(n_push=tk.n_push + start - cand) for tk in ticks[:n_check]]
        est = make_estimator(config.estimator, config.vehicle, load_sensor=load_sensor, rate_hz=config.rate_hz,
                             delay_s=config.delay_s)
        _, extra = _replay_ticks(events, meas_pos, meas, cand, trial, est, config, output, load_sensor, None, memo)
        if extra.get("cmp_exact") and all(extra["cmp_exact"]):
            how = "filter start found by matching the first setpoints"
            return cand, [tk._replace(n_push=tk.n_push + start - cand) for tk in ticks], how
    return start, ticks, "no filter start reproduced the first setpoints: approximate"


def replay(sc: Scan, inv: dict[str, Any], config: ReplayConfig,
           progress: Callable[[float], None] | None = None) -> ReplayResult:
    """Pass 2 (see module docstring). The log must be :func:`replayable`. ValueError when a live tick log is
    given that does not belong to this tlog. The cyclic garbage collector is paused meanwhile."""
    with _collector_paused():
        return _replay(sc, inv, config, progress)


def _replay(sc: Scan, inv: dict[str, Any], config: ReplayConfig,
            progress: Callable[[float], None] | None) -> ReplayResult:
    from estimators.factory import make_estimator
    from offboard.link.setpoints import MASKS

    ap = inv["autopilot_sysid"]
    vehicle = config.vehicle
    load_sensor = inv["has_load_sensor"] if config.load_sensor is None else config.load_sensor
    events = [e for e in sc.events if e.kind not in ("m", "clock", "landed") or e.sysid == ap]
    sp_all = [(i, e) for i, e in enumerate(events) if e.kind == "sp" and (e.sysid == ap or e.sysid == 0)]
    output = config.output or ("actuator" if any(isinstance(e.payload[0], ActuatorTarget) for _, e in sp_all)
                               else "attitude")
    kind_cls = AttitudeTarget if output == "attitude" else ActuatorTarget
    sp_events = [(i, e) for i, e in sp_all if isinstance(e.payload[0], kind_cls)]
    meas_pos = [i for i, e in enumerate(events) if e.kind == "m"]
    meas = [events[i].payload for i in meas_pos]
    memo: dict[str, Any] = {}  # what the passes of _replay_ticks over these events share

    if config.estimate_only:
        start, ticks = 0, []
        source = "grid"
    elif sp_events and config.live is not None:
        start, ticks = _plan_from_live(meas_pos, sp_events, config.live, output)
        source = "live tick log"
    elif sp_events:
        start, ticks = _plan_from_setpoints(events, meas_pos, meas, sp_events, output, config.rate_hz)
        source = "logged setpoints"
        if ticks and config.reference is not None and config.t_from is None:
            start, ticks, how = _find_start(events, meas_pos, meas, start, ticks, config, output, load_sensor,
                                            make_estimator, memo=memo)
            source += f" ({how})"
    else:
        start, ticks = 0, []
        source = "grid"
    t_from = -math.inf if config.t_from is None else config.t_from
    t_to = math.inf if config.t_to is None else config.t_to
    if ticks:
        k0 = next((k for k, tk in enumerate(ticks) if tk.t_v >= t_from), len(ticks))
        if k0 > 0 and k0 < len(ticks):  # start later: initialize where that tick's measurements end
            start += ticks[k0 - 1].n_push
            base = ticks[k0 - 1].n_push
            ticks = [tk._replace(n_push=tk.n_push - base) for tk in ticks[k0:]]
        elif k0 >= len(ticks):
            ticks = []
        ticks = [tk for tk in ticks if tk.t_v <= t_to]
    rate = config.rate_hz
    if len(ticks) > 2:
        d = np.diff(np.asarray([tk.t_v for tk in ticks]))
        d = d[d > 0]
        if len(d):
            rate = float(1.0 / np.median(d))
    estimator = make_estimator(config.estimator, vehicle, load_sensor=load_sensor, rate_hz=rate,
                               delay_s=config.delay_s)
    cols = columns_for(output)
    if ticks:
        data, extra = _replay_ticks(events, meas_pos, meas, start, ticks, estimator, config, output, load_sensor,
                                    progress, memo)
    else:
        source = f"grid at {rate:g} Hz"
        rows, extra = _replay_grid(events, estimator, vehicle, rate, t_from, t_to, load_sensor, output, progress)
        data = _table(rows, len(cols))
    if progress is not None:
        progress(1.0)
    metrics = _metrics(data, cols, inv, estimator, output, source, extra, config, rate, load_sensor, MASKS)
    return ReplayResult(data, cols, metrics, output)


def _logged_mask(events: list[Event]) -> str:
    """The setpoint mask the logged SET_ATTITUDE_TARGETs used (``attitude`` unless they all share another)."""
    from offboard.link.setpoints import MASKS

    masks = {round(e.payload[0].type_mask) for e in events
             if e.kind == "sp" and isinstance(e.payload[0], AttitudeTarget)}
    inverse = {v: k for k, v in MASKS.items()}
    return inverse.get(next(iter(masks)), "attitude") if len(masks) == 1 else "attitude"


def _replay_ticks(events: list[Event], meas_pos: list[int], meas: list[Any], start: int, ticks: list[_Tick],
                  estimator: Any, config: ReplayConfig, output: str, load_sensor: bool,
                  progress: Callable[[float], None] | None, memo: dict[str, Any] | None = None
                  ) -> tuple[np.ndarray, dict[str, Any]]:
    """Replay the controller ticks (see module docstring); returns the table and the comparison figures. memo: what
    depends on ``events`` only (the logged mask, the autopilot's side events), kept between the calls of one
    replay (``_find_start`` replays the first ticks once per candidate start)."""
    from offboard import smc
    from offboard.command_mapping import AutopilotModel, CommandMapper, MappingConfig

    if memo is None:
        memo = {}

    vehicle = config.vehicle
    prior = meas[:start]
    att = next((m for m in reversed(prior) if isinstance(m, Attitude)), None)
    pos = next((m for m in reversed(prior) if isinstance(m, PositionVelocity)), None)
    load = next((m for m in reversed(prior) if isinstance(m, LoadAngle)), None)
    if att is None or pos is None:  # nothing before the start: take the first ones after it
        att = att or next((m for m in meas[start:] if isinstance(m, Attitude)), None)
        pos = pos or next((m for m in meas[start:] if isinstance(m, PositionVelocity)), None)
    t_init = max(att.t if att else -math.inf, pos.t if pos else -math.inf)
    if not math.isfinite(t_init):
        t_init = ticks[0].t_v
    estimator.initialize(t_init, initial_guess(vehicle, pos, att, load))

    reference = None
    ox = oy = 0.0
    t_shift = 0.0  # 0: controller time from the tick plan; NaN: from the reference's given start
    if config.reference is not None:
        reference = config.reference.build()
        if config.reference.origin is not None:
            ox, oy = config.reference.origin
        elif pos is not None:
            r0 = reference.sample(0.0)
            ox, oy = pos.x - r0.fx[0], pos.y - r0.fy[0]
        if config.live is None and math.isfinite(config.reference.start):
            t_shift = math.nan  # controller time from the given start: t_ref = t_v - start
    params = smc.ControllerParams.for_vehicle(vehicle, switching=config.switching, epsilon=config.epsilon)
    from offboard.loop import ActuatorLag

    lag = ActuatorLag(vehicle.motor_time_constant)  # the filter is given what the motors deliver, as live
    mask = config.mask
    if mask is None:
        if "mask" not in memo:
            memo["mask"] = _logged_mask(events)
        mask = memo["mask"]
    ap_kw = dict(config.autopilot or {})
    for key in ("attitude_p", "rate_bandwidth"):
        if key in ap_kw:
            ap_kw[key] = tuple(ap_kw[key])
    mapper = CommandMapper(vehicle, MappingConfig(**{"output": output, "mask": mask, **(config.mapping or {})}),
                           AutopilotModel(**ap_kw))
    memory = smc.ControllerMemory()
    nan = math.nan
    nsp = 8 if output == "attitude" else 4
    nan_sp = (nan,) * nsp
    live = config.live
    rows: list[tuple[float, ...]] = []
    # the autopilot's ATTITUDE_TARGET and mode flag, in log order, merged by event index
    if "side" not in memo:
        memo["side"] = [(i, e) for i, e in enumerate(events) if e.kind in ("at", "mode")]
    side = memo["side"]
    si = 0
    last_at: tuple[float, ...] = (nan,) * 5
    offboard = nan
    last_load = (nan, nan)
    last_pos = (nan, nan, nan)
    pushed = 0
    step = smc.step
    n_t = len(ticks)
    nan4 = (nan,) * 4
    for k, tk in enumerate(ticks):
        if progress is not None and k % 2000 == 0:
            progress(k / n_t)
        hi = start + tk.n_push
        while pushed + start < hi:
            m = meas[start + pushed]
            estimator.push(m)
            if isinstance(m, LoadAngle):
                last_load = (m.alpha_x, m.alpha_y)
            elif isinstance(m, PositionVelocity):
                last_pos = (m.x, m.y, m.z)
            pushed += 1
        ev_idx = meas_pos[hi - 1] if hi > 0 and hi - 1 < len(meas_pos) else -1
        while si < len(side) and side[si][0] <= ev_idx:
            e = side[si][1]
            if e.kind == "at":
                last_at = (*e.payload[0], e.payload[1])
            else:
                offboard = 1.0 if e.payload else 0.0
            si += 1
        t_v = tk.t_v
        t_ref = tk.t_ref if t_shift == 0.0 else t_v - config.reference.start  # type: ignore[union-attr]
        est = estimator.estimate(t_v)
        if reference is not None:
            ref = reference.sample(t_ref)
            rfx = (ref.fx[0] + ox, *ref.fx[1:])
            rfy = (ref.fy[0] + oy, *ref.fy[1:])
            cmd, memory = step(t_ref, est, rfx, rfy, ref.z, ref.psi, memory, params)
            sp = mapper.map(t_ref, cmd, est)
            if math.isfinite(cmd.thrust + cmd.tau_phi + cmd.tau_theta + cmd.tau_psi):
                estimator.push_command(t_v, *lag(t_v, cmd.thrust, (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)))
            rows.append((t_v, t_ref, tk.lt, 1.0, *est.fx, *est.fy, *est[2:], *last_load, *last_pos, rfx[0], rfy[0],
                         ref.z[0], ref.psi[0], cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi, *_sp_fields(sp),
                         *tk.logged, *last_at, offboard, nan, nan))
        else:
            rows.append((t_v, t_ref, tk.lt, 1.0, *est.fx, *est.fy, *est[2:], *last_load, *last_pos, *nan4, *nan4,
                         *nan_sp, *tk.logged, *last_at, offboard, nan, nan))
    data = _table(rows, len(columns_for(output)))
    extra: dict[str, Any] = {"controller_ran": reference is not None, "origin": [ox, oy], "mapper": mapper,
                             "t_init": t_init, "start_index": start}
    _compare(data, columns_for(output), output, reference is not None, live,
             np.array([tk.live for tk in ticks], dtype=int), extra)
    return data, extra


def _table(rows: list[tuple[float, ...]], width: int) -> np.ndarray:
    """The (len(rows), width) float array of equal-length rows (``np.fromiter`` over the chained rows: about half the
    cost of ``np.array(rows)``, same values)."""
    return np.fromiter(itertools.chain.from_iterable(rows), float, len(rows) * width).reshape(len(rows), width)


def _quat_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angles (rad) between the rows of two (n, 4) arrays of unit quaternions, sign-insensitive:
    ``4 asin(|a - s b| / 2)`` with ``s = sign(a . b)``, well conditioned for small angles (``2 acos(|a . b|)``
    is not: float32 rounding alone would read as 5e-4 rad)."""
    s = np.where(np.sum(a * b, axis=1) >= 0.0, 1.0, -1.0)[:, None]
    d = np.sqrt(np.sum((a - s * b) ** 2, axis=1))
    return 4.0 * np.arcsin(np.minimum(1.0, 0.5 * d))


def _compare(data: np.ndarray, cols: tuple[str, ...], output: str, controller_ran: bool, live: LiveRun | None,
             live_idx: np.ndarray, extra: dict[str, Any]) -> None:
    """Recomputed vs logged setpoints, logged vs the autopilot's ATTITUDE_TARGET, and replay vs the live tick
    log, over all ticks at once; fills the ``live_*_diff`` columns and the comparison entries of ``extra``."""
    if len(data) == 0:
        return
    c = {n: i for i, n in enumerate(cols)}
    nsp = 8 if output == "attitude" else 4
    s0, l0 = c["sp_" + (SP_ATT if output == "attitude" else SP_ACT)[0]], c["log_" + (SP_ATT if output == "attitude"
                                                                                       else SP_ACT)[0]]
    rec, logged = data[:, s0:s0 + nsp], data[:, l0:l0 + nsp]
    if controller_ran:
        extra["cmp_exact"] = np.all(rec.astype(np.float32) == logged, axis=1).tolist()
        if output == "attitude":
            extra["cmp_angle"] = _quat_angles(rec[:, :4], logged[:, :4]).tolist()
            extra["cmp_fields"] = np.abs(rec[:, 4:] - logged[:, 4:]).tolist()
        else:
            extra["cmp_fields"] = np.abs(rec - logged).tolist()
    if output == "attitude":
        ap = data[:, c["ap_q_w"]:c["ap_q_w"] + 4]
        ok = np.all(np.isfinite(ap), axis=1)
        extra["ap_angle"] = _quat_angles(ap[ok], logged[ok, :4]).tolist()
    if live is not None:
        ok = live_idx >= 0
        e0 = c["Fx"]
        d_est = np.max(np.abs(data[ok, e0:e0 + len(EST_COLUMNS)] - live.est[live_idx[ok]]), axis=1)
        data[ok, c["live_est_diff"]] = d_est
        extra["live_est"] = d_est.tolist()
        if controller_ran:
            d_sp = np.max(np.abs(rec[ok] - live.sp[live_idx[ok], :nsp]), axis=1)
            data[ok, c["live_sp_diff"]] = d_sp
            extra["live_sp"] = d_sp.tolist()


def _replay_grid(events: list[Event], estimator: Any, vehicle: Vehicle, rate: float, t_from: float, t_to: float,
                 load_sensor: bool, output: str, progress: Callable[[float], None] | None
                 ) -> tuple[list[tuple[float, ...]], dict[str, Any]]:
    """Estimation only, on a fixed grid of vehicle time driven by the newest sample time (see module docstring).

    The filter has no ground contact in its model, so it runs only while the vehicle flies: from the first moment
    attitude, position (and the cable angle, when used) have been reported and EXTENDED_SYS_STATE (when the log
    has it) says IN_AIR, until it reports the vehicle landed (restarted at the next take-off) or the vehicle's clock
    goes back (a reboot). Each start initializes the filter from the latest telemetry, as the live loop does.
    The commands the vehicle flew are unknown: the filter is told hover thrust and no torque at every tick."""
    nan = math.nan
    nsp = 8 if output == "attitude" else 4
    tail = (nan,) * (8 + 2 * nsp)
    rows: list[tuple[float, ...]] = []
    period = 1.0 / rate
    hover_thrust = vehicle.hover_thrust
    zero3 = (0.0, 0.0, 0.0)
    has_landed_info = any(e.kind == "landed" for e in events)
    airborne = not has_landed_info
    running = False
    last_att: Attitude | None = None
    last_pv: PositionVelocity | None = None
    last_ld: LoadAngle | None = None
    vnow = -math.inf
    next_tick = math.inf
    last_load = (nan, nan)
    last_pos = (nan, nan, nan)
    last_at: tuple[float, ...] = (nan,) * 5
    offboard = nan
    n = len(events)
    resets = 0
    starts = 0
    t_init: float | None = None
    for idx, e in enumerate(events):
        if progress is not None and idx % 4000 == 0:
            progress(idx / n)
        kind = e.kind
        if kind == "m":
            m = e.payload
            if m.t < t_from or m.t > t_to:
                continue
            if isinstance(m, Attitude) and m.t < vnow - REBOOT_JUMP_S:
                resets += 1  # the vehicle's clock went back: a reboot; start afresh
                running = False
                last_pv = last_ld = None
                vnow = -math.inf
            if isinstance(m, Attitude):
                last_att = m
            elif isinstance(m, PositionVelocity):
                last_pv = m
                last_pos = (m.x, m.y, m.z)
            elif isinstance(m, LoadAngle):
                last_ld = m
                last_load = (m.alpha_x, m.alpha_y)
            if not running:
                if airborne and last_att is not None and last_pv is not None and (last_ld is not None
                                                                                  or not load_sensor):
                    t0 = max(last_att.t, last_pv.t)
                    estimator.initialize(t0, initial_guess(vehicle, last_pv, last_att,
                                                           last_ld if load_sensor else None))
                    estimator.push_command(t0, hover_thrust, zero3)
                    running = True
                    starts += 1
                    t_init = t0 if t_init is None else t_init
                    vnow = t0
                    next_tick = t0 + period
                continue
            if m.t > vnow:
                vnow = m.t
            while next_tick <= vnow:
                est = estimator.estimate(next_tick)
                estimator.push_command(next_tick, hover_thrust, zero3)
                rows.append((next_tick, nan, e.lt, 0.0, *est.fx, *est.fy, *est[2:], *last_load, *last_pos, *tail,
                             *last_at, offboard, nan, nan))
                next_tick += period
            estimator.push(m)
        elif kind == "landed":
            airborne = e.payload == 2  # MAV_LANDED_STATE_IN_AIR
            if not airborne:
                running = False
        elif kind == "mode":
            offboard = 1.0 if e.payload else 0.0
        elif kind == "at":
            last_at = (*e.payload[0], e.payload[1])
    return rows, {"controller_ran": False, "t_init": t_init, "clock_resets": resets, "filter_starts": starts,
                  "airborne_gating": has_landed_info}


def _stats(x: np.ndarray) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return {"max": None, "rms": None, "p99": None}
    return {"max": float(np.max(np.abs(x))), "rms": float(np.sqrt(np.mean(x * x))),
            "p99": float(np.percentile(np.abs(x), 99))}


def _metrics(data: np.ndarray, cols: tuple[str, ...], inv: dict[str, Any], estimator: Any, output: str,
             source: str, extra: dict[str, Any], config: ReplayConfig, rate: float, load_sensor: bool,
             masks: dict[str, int]) -> dict[str, Any]:
    """The metrics.json dictionary of a replay (sections: log, estimation, tracking, setpoint_agreement,
    live_agreement, config)."""
    c = {n: i for i, n in enumerate(cols)}
    col = lambda n: data[:, c[n]]  # noqa: E731 - short accessor
    n = len(data)
    t = col("t") if n else np.zeros(0)
    e0 = c["Fx"]
    est: dict[str, Any] = {
        "ticks": n,
        "tick_source": source,
        "rate_hz": rate,
        "estimator": config.estimator,
        "load_sensor_used": load_sensor,
        "initialized_at_s": extra.get("t_init"),
        "filter_starts": extra.get("filter_starts", 1),
        "airborne_only": bool(extra.get("airborne_gating", False)),
        "vehicle_time_span_s": [float(t[0]), float(t[-1])] if n else None,
        "estimator_stats": estimator.stats(),
        "all_finite": bool(np.all(np.isfinite(data[:, e0:e0 + len(EST_COLUMNS)]))) if n else True,
    }
    if n:
        ax, ay = col("alpha_x"), col("alpha_y")
        alpha = np.sqrt(ax * ax + ay * ay)
        est["swing_max_rad"] = float(np.max(alpha))
        est["swing_rms_rad"] = float(np.sqrt(np.mean(alpha * alpha)))
        ell = config.vehicle.cable_length
        ok = np.isfinite(col("pos_x"))
        if np.any(ok):  # the vehicle position implied by the estimate (F - l alpha) vs the autopilot's latest
            dx = col("Fx") - ell * col("alpha_y") - col("pos_x")
            dy = col("Fy") - ell * col("alpha_x") - col("pos_y")
            est["position_vs_autopilot_m"] = _stats(np.sqrt(dx * dx + dy * dy)[ok])
            est["height_vs_autopilot_m"] = _stats((col("z") - col("pos_z"))[ok])
        if np.any(np.isfinite(col("meas_alpha_x"))):
            est["alpha_x_vs_sensor"] = _stats(ax - col("meas_alpha_x"))
            est["alpha_y_vs_sensor"] = _stats(ay - col("meas_alpha_y"))
    tracking: dict[str, Any] | None = None
    agreement: dict[str, Any] | None = None
    cmp_fields = extra.get("cmp_fields", [])
    cmp_angle = extra.get("cmp_angle", [])
    if extra.get("controller_ran") and n:
        tracking = {"note": "errors of the ESTIMATED flat outputs, height and heading against the reference"}
        for name, a, b in (("e_Fx", "Fx", "Fx_ref"), ("e_Fy", "Fy", "Fy_ref"), ("e_z", "z", "z_ref")):
            tracking[name] = _stats(col(a) - col(b))
        tracking["e_psi"] = _stats(np.remainder(col("psi") - col("psi_ref") + math.pi, 2 * math.pi) - math.pi)
        agreement = {"ticks_compared": len(cmp_fields), "mapper_fallbacks": extra["mapper"].fallbacks,
                     "float32_identical": int(sum(extra.get("cmp_exact", [])))}
        if cmp_fields:
            f = np.asarray(cmp_fields)
            names = SP_ATT[4:] if output == "attitude" else SP_ACT
            for i, nm in enumerate(names):
                agreement[nm] = _stats(f[:, i])
            if output == "attitude":
                agreement["attitude_angle_rad"] = _stats(np.asarray(cmp_angle))
            agreement["max_abs_difference"] = max(float(np.max(f)), max(cmp_angle) if cmp_angle else 0.0)
    if extra.get("ap_angle"):
        agreement = agreement or {}
        agreement["logged_vs_autopilot_attitude_target_rad"] = _stats(np.asarray(extra["ap_angle"]))
    live: dict[str, Any] | None = None
    if extra.get("live_est"):
        le = np.asarray(extra["live_est"])
        live = {"ticks": len(le), "estimate_max_abs_difference": float(np.max(le)),
                "estimate_identical": int(np.sum(le == 0.0))}
        if extra.get("live_sp"):
            ls = np.asarray(extra["live_sp"])
            live["setpoint_max_abs_difference"] = float(np.max(ls))
            live["setpoint_identical"] = int(np.sum(ls == 0.0))
    ref = config.reference
    notes = []
    if source != "grid" and not source.startswith("grid") and not extra.get("controller_ran"):
        notes.append("the log holds an offboard flight but the reference it flew is unknown: only the estimator ran "
                     "(give --scenario or --trajectory, or keep the run's metrics.json beside the tlog)")
    est["notes"] = notes
    return {
        "log": inv,
        "estimation": est,
        "tracking": tracking,
        "setpoint_agreement": agreement,
        "live_agreement": live,
        "config": {
            "vehicle": config.vehicle.name,
            "from_s": config.t_from, "to_s": config.t_to, "output": output, "switching": config.switching,
            "epsilon": config.epsilon, "delay_s": config.delay_s,
            "reference": None if ref is None else {"scenario": ref.scenario, "origin": extra.get("origin")},
        },
    }


__all__ = [
    "EST_COLUMNS", "Event", "LiveLogMismatchError", "LiveRun", "ReferenceSpec", "ReplayConfig", "ReplayResult",
    "Scan", "SystemInfo", "columns_for", "initial_guess", "inventory", "is_offboard_mode", "load_live_table",
    "replay", "replayable", "scan", "vehicle_time_of",
]
