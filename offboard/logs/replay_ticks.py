"""The replay of an offboard flight, tick by tick (``offboard.logs.replay``): the measurements logged before each
setpoint pushed into the estimator, the one controller tick (``offboard.control.tick.ControlTick``) and the
command mapping run, and the recomputed setpoint compared with the logged one. Model frame, SI units, radians.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from estimators.model.measurements import Attitude, LoadAngle, PositionVelocity
from offboard.flight.link.setpoints import AttitudeTarget
from offboard.logs.log_inventory import (
    Event,
)
from offboard.logs.replay_compare import as_table, compare_ticks
from offboard.logs.replay_plan import ReplayTick, sp_fields
from offboard.logs.replay_records import ReplayConfig, columns_for, initial_guess


def logged_mask(events: list[Event]) -> str:
    """The setpoint mask the logged SET_ATTITUDE_TARGETs used (``attitude`` unless they all share another)."""
    from offboard.flight.link.setpoints import MASKS

    masks = {
        round(e.payload[0].type_mask) for e in events if e.kind == "sp" and isinstance(e.payload[0], AttitudeTarget)
    }
    inverse = {v: k for k, v in MASKS.items()}
    return inverse.get(next(iter(masks)), "attitude") if len(masks) == 1 else "attitude"


def _row_tail(
    logged: tuple[float, ...], last_at: tuple[float, ...], offboard: float, last_att3: tuple[float, ...], estimator: Any
) -> tuple[float, ...]:
    """A replayed row's columns after the setpoint, alike with or without a controller: what the log held (``logged``),
    the autopilot's latest ATTITUDE_TARGET and OFFBOARD flag, the logged attitude, the columns a replay has no value
    for, and the filter's sigmas and innovations."""
    nan = math.nan
    return (
        *logged,
        *last_at,
        offboard,
        nan,
        nan,
        *last_att3,
        0.0,
        0.0,
        nan,
        *estimator.sigmas(),
        *estimator.innovations(),
    )


def replay_ticks(
    events: list[Event],
    meas_pos: list[int],
    meas: list[Any],
    start: int,
    ticks: list[ReplayTick],
    estimator: Any,
    config: ReplayConfig,
    output: str,
    load_sensor: bool,
    progress: Callable[[float], None] | None,
    memo: dict[str, Any] | None = None,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Replay the controller ticks (see module docstring); returns the table and the comparison figures. memo: what
    depends on ``events`` only (the logged mask, the autopilot's side events), kept between the calls of one
    replay (``_find_start`` replays the first ticks once per candidate start)."""
    from offboard.control import smc
    from offboard.control.controllers.sliding_mode import law_for
    from offboard.control.tick import ActuatorLag, ControlTick
    from offboard.flight.command_mapping import CommandMapper, MappingConfig
    from offboard.flight.link.autopilot_model import AutopilotModel
    from offboard.flight.loop import prefuse_lead

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
    ox = oy = oz = 0.0
    t_shift = 0.0  # 0: controller time from the tick plan; NaN: from the reference's given start
    if config.reference is not None:
        reference = config.reference.build()
        oz = config.reference.ground_z
        if config.reference.origin is not None:
            ox, oy = config.reference.origin
        elif pos is not None:
            r0 = reference.sample(0.0)
            ox, oy = pos.x - r0.fx[0], pos.y - r0.fy[0]
        if config.live is None and math.isfinite(config.reference.start):
            t_shift = math.nan  # controller time from the given start: t_ref = t_v - start
    params = smc.ControllerParams.for_vehicle(
        vehicle,
        switching=config.switching,
        epsilon=config.epsilon,
        shared_roll_pitch=config.shared_roll_pitch,
        layer_errors=config.layer_errors,
        actuation_lag_s=config.actuation_lag_s,
    )
    if config.gain_scale != 1.0:  # as the live loop scheduled them (FlightLoop._schedule_gains)
        params = replace(params, gains=params.gains.scaled(config.gain_scale))
    lag = ActuatorLag(vehicle.motor_time_constant)  # the filter is given what the motors deliver, as live
    mask = config.mask
    if mask is None:
        if "mask" not in memo:
            memo["mask"] = logged_mask(events)
        mask = memo["mask"]
    ap_kw = dict(config.autopilot or {})
    for key in ("attitude_p", "rate_bandwidth", "rate_integral", "unit_torque"):
        if ap_kw.get(key) is not None:
            ap_kw[key] = tuple(ap_kw[key])
    mapping = MappingConfig(**{"output": output, "mask": mask, **(config.mapping or {})})
    from offboard.control.controllers import registry
    from offboard.flight.attitude_mapping import AttitudeLawMapper, inner_loop_of
    from offboard.logs.replay import live_tuning

    autopilot = AutopilotModel(**ap_kw)
    drag_ff = registry.drag_in_law(live_tuning(config)) if config.drag_feedforward is None else config.drag_feedforward
    law: Any = None
    level = config.law
    if config.controller is not None:  # a controller of the registry, as slung fly --controller flew it
        from offboard.control.controllers.flight_output import registered_as_flown

        law, level = registered_as_flown(
            config.controller,
            vehicle,
            output,
            switching=config.switching,
            epsilon=config.epsilon,
            drag_feedforward=drag_ff,
        )
    elif config.law == "attitude":  # as the live loop builds it (offboard.flight.fly_cli.fly, FlightLoop.run)
        from offboard.control import smc_attitude

        params = smc_attitude.AttitudeParams.for_vehicle(
            vehicle,
            overrides=dict(vehicle.gains),
            switching=config.switching,
            tilt_max=mapping.max_tilt,
            drag_feedforward=drag_ff,
        ).with_inner(inner_loop_of(autopilot))
    if law is None:
        law = law_for(params)
    mapper: CommandMapper = (
        AttitudeLawMapper(vehicle, mapping, autopilot)
        if level == "attitude"
        else CommandMapper(vehicle, mapping, autopilot)
    )
    tick = None
    if reference is not None:  # the same tick as the live loop (offboard.control.tick)
        tick = ControlTick(law, reference, estimator=estimator, mapper=mapper, lag=lag, origin=(ox, oy, oz))
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
    last_att3 = (nan, nan, nan)
    pushed = 0
    n_t = len(ticks)
    nan4 = (nan,) * 4
    # the live loop's fusion between ticks, at the same place (after the tick's row) and with the same lead
    prefuse = getattr(estimator, "prefuse", None)
    prefuse_ahead = prefuse_lead(1.0 / config.rate_hz)
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
            elif isinstance(m, Attitude):
                last_att3 = (m.phi, m.theta, m.psi)
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
        if tick is not None:
            est, ref, rfx, rfy, rz, cmd, sp, _ = tick(t_v, t_ref)
            rows.append(
                (
                    t_v,
                    t_ref,
                    tk.lt,
                    1.0,
                    *est.fx,
                    *est.fy,
                    *est[2:],
                    *last_load,
                    *last_pos,
                    rfx[0],
                    rfy[0],
                    rz[0],
                    ref.psi[0],
                    cmd.thrust,
                    cmd.tau_phi,
                    cmd.tau_theta,
                    cmd.tau_psi,
                    *sp_fields(sp),
                    *_row_tail(tk.logged, last_at, offboard, last_att3, estimator),
                )
            )
        else:
            est = estimator.estimate(t_v)
            rows.append(
                (
                    t_v,
                    t_ref,
                    tk.lt,
                    1.0,
                    *est.fx,
                    *est.fy,
                    *est[2:],
                    *last_load,
                    *last_pos,
                    *nan4,
                    *nan4,
                    *nan_sp,
                    *_row_tail(tk.logged, last_at, offboard, last_att3, estimator),
                )
            )
        if prefuse is not None:
            prefuse(t_v + prefuse_ahead)
    data = as_table(rows, len(columns_for(output)))
    extra: dict[str, Any] = {
        "controller_ran": reference is not None,
        "origin": [ox, oy],
        "mapper": mapper,
        "t_init": t_init,
        "start_index": start,
    }
    compare_ticks(
        data,
        columns_for(output),
        output,
        reference is not None,
        live,
        np.array([tk.live for tk in ticks], dtype=int),
        extra,
    )
    return data, extra
