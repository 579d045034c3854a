"""tlog -> the live loop's measurements -> the same estimator and controller: what a flight log contains, what the
filter makes of it, and what the controller would have sent.

Two passes over memory, one over the file:

1. **Read and inventory** (``offboard.logs.log_inventory``: :func:`scan`, :func:`inventory`): every packet of the tlog
   (``offboard.logs.tlog``) counted per system and type, the autopilot identified, telemetry decoded by the live
   link's own decoder into measurement records on the vehicle's own time, setpoints and events kept in log
   order.
2. **Replay** (:func:`replay`): the measurements of the autopilot's system are pushed into the estimator
   (``estimators.make_estimator``) in the order the logger received them. Ticks:

   - where the log holds an offboard flight (setpoints sent to the autopilot), one tick per logged setpoint:
     the estimator sees exactly the measurements logged before it, the controller (``offboard.control.smc.step``) and
     the command mapping (``offboard.flight.command_mapping``) run, and the recomputed setpoint is compared with the
     logged one. The controller needs the reference the flight used (scenario name and its start time, from
     the run's ``metrics.json`` beside the tlog or from the command line); without it only the estimator runs.
   - elsewhere the estimator ticks on a fixed grid (``rate_hz``) of vehicle time, driven by the newest sample
     time seen (a loop with no latency): estimation only.

Everything is in the model frame (world NWU z up, body FLU), SI units and radians; time ``t`` is the vehicle's
time since boot (s). Output: :class:`ReplayResult` (a table with one row per tick, ``metrics``), written by
:func:`write_outputs` as ``timeseries.slts``, ``metrics.json`` and figures.

This module is the driver and the API; the parts: ``replay_records`` (configuration, result, the live loop's log
read back), ``replay_plan`` (which ticks), ``replay_ticks`` (the offboard ticks), ``replay_grid`` (estimation
only), ``replay_compare`` (comparison, timeline, metrics).
"""

from __future__ import annotations

import bisect
import contextlib
import dataclasses
import gc
import math
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np

from estimators.model.measurements import Attitude, Imu
from offboard.flight.link.setpoints import ActuatorTarget, AttitudeTarget
from offboard.logs.flight_modes import is_offboard_mode
from offboard.logs.log_inventory import (
    Event,
    Scan,
    Segment,
    SystemInfo,
    clock_jump,
    flight_segments,
    records_by_epoch,
    vehicle_time_of,
)
from offboard.logs.log_inventory import scan as _scan
from offboard.logs.log_summary import inventory, replayable
from offboard.logs.replay_compare import as_table, replay_metrics, swing_vs_truth, timeline
from offboard.logs.replay_grid import replay_grid
from offboard.logs.replay_health import fit_sensor_noise, tuning_for
from offboard.logs.replay_plan import ReplayTick, plan_from_live, plan_from_setpoints
from offboard.logs.replay_records import (
    EST_COLUMNS,
    LiveLogMismatchError,
    LiveRun,
    ReferenceSpec,
    ReplayConfig,
    ReplayResult,
    columns_for,
    initial_guess,
    load_live_table,
)
from offboard.logs.replay_ticks import replay_ticks


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
    """Pass 1: :func:`offboard.logs.log_inventory.scan`, with the cyclic garbage collector paused."""
    with _collector_paused():
        return _scan(messages)


# ---------------------------------------------------------------------------------------------------------------
# pass 2: replay


def live_tuning(config: ReplayConfig) -> Any:
    """The tuning the live run's filter was built with (None: the defaults): ``--external-feedforward`` is the one
    setting of it a flight chooses."""
    if not config.external_feedforward or config.estimator != "kf":
        return None
    from estimators.filters.measured_model import FEEDFORWARD_TUNING

    return FEEDFORWARD_TUNING


def _find_start(
    events: list[Event],
    meas_pos: list[int],
    meas: list[Any],
    start: int,
    ticks: list[ReplayTick],
    config: ReplayConfig,
    output: str,
    load_sensor: bool,
    make_estimator: Callable[..., Any],
    n_check: int = 8,
    memo: dict[str, Any] | None = None,
) -> tuple[int, list[ReplayTick], str]:
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
        est = make_estimator(
            config.estimator,
            config.vehicle,
            load_sensor=load_sensor,
            rate_hz=config.rate_hz,
            delay_s=config.delay_s,
            tuning=live_tuning(config),
        )
        _, extra = replay_ticks(events, meas_pos, meas, cand, trial, est, config, output, load_sensor, None, memo)
        if extra.get("cmp_exact") and all(extra["cmp_exact"]):
            how = "filter start found by matching the first setpoints"
            return cand, [tk._replace(n_push=tk.n_push + start - cand) for tk in ticks], how
    return start, ticks, "no filter start reproduced the first setpoints: approximate"


def _end_at_flip(
    events: list[Event], ap: int | None, segments: list[Segment]
) -> tuple[list[Segment], list[dict[str, Any]]]:
    """Each airborne segment cut where the vehicle turned upside down (body z pointing below the horizon: a
    flip, a crash): no multirotor flies that way, and the filter's model of a flying vehicle does not hold after it
    (the autopilot may not notice the vehicle is on the ground). Returns the segments and the flips."""
    out, flips = [], []
    firsts: dict[int, float] = {}
    for epoch, m in records_by_epoch(events, ap):
        if isinstance(m, Attitude) and math.cos(m.phi) * math.cos(m.theta) < 0.0:
            for i, sg in enumerate(segments):
                if i not in firsts and sg.holds(epoch, m.t):
                    firsts[i] = m.t
    for i, sg in enumerate(segments):
        if i in firsts:
            flips.append({"t_s": firsts[i], "segment": i, "text": "the vehicle turned upside down: replay ends"})
            if firsts[i] - sg.t0 > 1.0:
                out.append(Segment(sg.epoch, sg.t0, firsts[i]))
        else:
            out.append(sg)
    return out, flips


#: below this logged IMU rate (Hz) a replay without a load leaves the accelerometer out (aliased vibration)
MIN_IMU_RATE_HZ = 20.0


def _load_decision(
    events: list[Event], ap: int | None, segments: list[Any], vehicle: Any, load_sensor: bool
) -> tuple[Any, dict[str, Any]]:
    """Is a load attached (``offboard.logs.replay_load``: from the log's IMU and attitude, not from its name)? The
    vehicle the estimator then runs with (without a cable-angle sensor and without a load: the vehicle file's load
    removed, so the filter has no swing states to diverge; with a load: the identified mass and cable length in
    place of the file's) and metrics.json's ``load`` block."""
    from offboard.logs.replay_load import identify_from_log, load_block

    ident = identify_from_log(events, ap, segments, vehicle)
    block = load_block(ident, vehicle, load_sensor)
    if ident is not None and not ident.attached and not load_sensor and vehicle.mass_load > 0.0:
        block["estimator_vehicle"] = "the vehicle file's load removed: no swing states"
        vehicle = vehicle.with_changes(mass_load=0.0)
    elif ident is not None and ident.attached and ident.mass_kg is not None and ident.cable_m is not None:
        # the filter's pendulum is the one the log shows, not the vehicle file's guess
        block["estimator_vehicle"] = "the identified load"
        vehicle = vehicle.with_changes(mass_load=ident.mass_kg, cable_length=ident.cable_m)
    block["estimator_load"] = {"mass_kg": vehicle.mass_load, "cable_m": vehicle.cable_length}
    return vehicle, block


def replay(
    sc: Scan, inv: dict[str, Any], config: ReplayConfig, progress: Callable[[float], None] | None = None
) -> ReplayResult:
    """Pass 2 (see module docstring). The log must be :func:`replayable`. ValueError when a live tick log is
    given that does not belong to this tlog. The cyclic garbage collector is paused meanwhile."""
    with _collector_paused():
        return _replay(sc, inv, config, progress)


def _replay(
    sc: Scan, inv: dict[str, Any], config: ReplayConfig, progress: Callable[[float], None] | None
) -> ReplayResult:
    from estimators.filters.factory import make_estimator
    from offboard.flight.link.setpoints import MASKS

    ap = inv["autopilot_sysid"]
    vehicle = config.vehicle
    load_sensor = inv["has_load_sensor"] if config.load_sensor is None else config.load_sensor
    events = [e for e in sc.events if e.kind not in ("m", "clock", "landed") or e.sysid == ap]
    sp_all = [(i, e) for i, e in enumerate(events) if e.kind == "sp" and (e.sysid == ap or e.sysid == 0)]
    output = config.output or (
        "actuator" if any(isinstance(e.payload[0], ActuatorTarget) for _, e in sp_all) else "attitude"
    )
    kind_cls = AttitudeTarget if output == "attitude" else ActuatorTarget
    sp_events = [(i, e) for i, e in sp_all if isinstance(e.payload[0], kind_cls)]
    meas_pos = [i for i, e in enumerate(events) if e.kind == "m"]
    meas = [events[i].payload for i in meas_pos]
    memo: dict[str, Any] = {}  # what the passes of replay_ticks over these events share

    if config.estimate_only:
        start, ticks = 0, []
        source = "grid"
    elif sp_events and config.live is not None:
        start, ticks = plan_from_live(meas_pos, sp_events, config.live, output)
        source = "live tick log"
    elif sp_events:
        start, ticks = plan_from_setpoints(events, meas_pos, meas, sp_events, output, config.rate_hz)
        source = "logged setpoints"
        if ticks and config.reference is not None and config.t_from is None:
            start, ticks, how = _find_start(
                events, meas_pos, meas, start, ticks, config, output, load_sensor, make_estimator, memo=memo
            )
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
    cols = columns_for(output)
    if ticks:  # the live loop's own filter, as it was built (bit-identical replay)
        estimator = make_estimator(
            config.estimator,
            vehicle,
            load_sensor=load_sensor,
            rate_hz=rate,
            delay_s=config.delay_s,
            tuning=live_tuning(config),
        )
        data, extra = replay_ticks(
            events, meas_pos, meas, start, ticks, estimator, config, output, load_sensor, progress, memo
        )
    else:  # estimation only: the filter's measurement noise fitted to the log's own sensors
        from estimators.filters.factory import default_tuning

        segments, _ = flight_segments(sc)
        segments, flips = _end_at_flip(events, ap, segments)
        vehicle, load = _load_decision(events, ap, segments, vehicle, load_sensor)
        config = dataclasses.replace(config, vehicle=vehicle)
        fitted = fit_sensor_noise(meas)
        if vehicle.mass_load == 0.0 and (fitted["rates_hz"].get("imu") or 0.0) < MIN_IMU_RATE_HZ:
            # an IMU logged this slowly aliases the vehicle's vibration into the band the filter tracks; with no
            # swing to estimate from it, the filter runs on the attitude and the position alone
            events = [e for e in events if not (e.kind == "m" and isinstance(e.payload, Imu))]
            load["estimator_imu"] = f"not used: logged at {fitted['rates_hz']['imu']:.1f} Hz"
        tuning = tuning_for(fitted, default_tuning(config.estimator))
        fastest = max((r for k, r in fitted["rates_hz"].items() if k in ("imu", "attitude") and r), default=None)
        if fastest is not None and fastest < rate:  # ticking faster than the log's fastest sensor adds nothing
            rate = max(1.0, round(fastest))
        estimator = make_estimator(
            config.estimator, vehicle, load_sensor=load_sensor, rate_hz=rate, delay_s=config.delay_s, tuning=tuning
        )
        source = f"grid at {rate:g} Hz"
        rows, extra = replay_grid(
            events, estimator, vehicle, rate, t_from, t_to, load_sensor, output, progress, segments
        )
        extra["sensor_noise"] = {
            "fitted": fitted,
            "filter_sigma": {k: getattr(tuning, k) for k in ("sigma_acc", "sigma_rate", "sigma_tilt", "sigma_pos_xy")},
        }
        extra["segments"] = [sg.as_dict() for sg in segments]
        extra["load"] = load
        if flips:
            extra["flips"] = flips
        data = as_table(rows, len(cols))
    if progress is not None:
        progress(1.0)
    metrics = replay_metrics(data, cols, inv, estimator, output, source, extra, config, rate, load_sensor, MASKS)
    metrics["timeline"] = timeline(events, extra.get("divergences", []))
    for flip in extra.get("flips", []):
        metrics["timeline"].append({"t_s": flip["t_s"], "kind": "flip", "text": flip["text"]})
        metrics["estimation"].setdefault("flips", []).append(flip)
    if "load" in extra:
        metrics["load"] = extra["load"]
        if extra["load"].get("attached") is False:  # no swing states: no swing figure either
            for k in ("swing_max_rad", "swing_rms_rad"):
                metrics["estimation"].pop(k, None)
    truth: np.ndarray | None = None
    if inv.get("payload_truth") is not None and len(data):
        metrics["estimation"]["swing_vs_truth"], truth = swing_vs_truth(events, data, cols, ap, inv.get("load_sysid"))
    return ReplayResult(data, cols, metrics, output, truth)


__all__ = [
    "EST_COLUMNS",
    "Event",
    "LiveLogMismatchError",
    "LiveRun",
    "ReferenceSpec",
    "ReplayConfig",
    "ReplayResult",
    "Scan",
    "SystemInfo",
    "clock_jump",
    "columns_for",
    "flight_segments",
    "initial_guess",
    "inventory",
    "is_offboard_mode",
    "load_live_table",
    "replay",
    "replayable",
    "scan",
    "vehicle_time_of",
]
