"""tlog -> the live loop's measurements -> the same estimator and controller: what a flight log contains, what the
filter makes of it, and what the controller would have sent.

Two passes over memory, one over the file:

1. **Read and inventory** (:func:`scan`): every packet of the tlog (``offboard.tlog``) is counted per system and
   message type; HEARTBEATs give the autopilot's system id, flavour (PX4 / ArduPilot / other), vehicle type and
   flight mode; telemetry of every system is decoded into the estimator's measurement records by the live
   link's own decoder (``offboard.link.telemetry.TelemetryDecoder``, model frame, times from the vehicle's
   ``time_boot_ms`` / ``time_usec``, never the logger's clock); setpoints sent to the autopilot
   (SET_ATTITUDE_TARGET, SET_ACTUATOR_CONTROL_TARGET) and the autopilot's own ATTITUDE_TARGET are kept in
   log order beside them.
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

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimators.control_state import ControlState
from estimators.flatness import flat_chain, flat_constants, world_tilt
from estimators.measurements import Attitude, LoadAngle, PositionVelocity
from estimators.vehicle import Vehicle
from offboard.link.setpoints import ActuatorTarget, AttitudeTarget
from offboard.link.setpoints import decode as decode_setpoint
from offboard.link.telemetry import LOAD_ANGLE_NAME, TelemetryDecoder

# ---------------------------------------------------------------------------------------------------------------
# MAVLink enums used by the inventory (common.xml)

MAV_AUTOPILOT_NAMES = {0: "generic", 3: "ardupilot", 8: "invalid", 12: "px4"}
MAV_TYPE_NAMES = {
    0: "generic", 1: "fixed wing", 2: "quadrotor", 3: "coaxial", 4: "helicopter", 6: "ground control station",
    10: "ground rover", 11: "surface boat", 12: "submarine", 13: "hexarotor", 14: "octorotor", 15: "tricopter",
    18: "onboard controller", 19: "VTOL tailsitter duo", 20: "VTOL tailsitter quad", 21: "VTOL tiltrotor",
    22: "VTOL fixed rotor", 23: "VTOL tailsitter", 26: "gimbal", 27: "ADS-B", 29: "dodecarotor",
}
MULTIROTOR_TYPES = frozenset({2, 3, 4, 13, 14, 15, 29})
FIXED_WING_TYPES = frozenset({1, 16, 19, 20, 21, 22, 23, 24, 25})
#: types that are never the vehicle itself (ground stations, companions, gimbals, cameras, ...)
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31})
PX4_MAIN_MODE_OFFBOARD = 6
ARDUPILOT_COPTER_GUIDED = (4, 20)  # GUIDED, GUIDED_NOGPS
SETPOINT_TYPES = ("SET_ATTITUDE_TARGET", "SET_ACTUATOR_CONTROL_TARGET")
TELEMETRY_TYPES = frozenset({"ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "ODOMETRY", "HIGHRES_IMU",
                             "SCALED_IMU", "DEBUG_VECT"})


def vehicle_time_of(msg: Any) -> float | None:
    """The vehicle's own time of a message (s since its boot) from ``time_usec`` or ``time_boot_ms``, else None."""
    d = msg.__dict__
    if "time_usec" in d:
        return d["time_usec"] * 1e-6
    if "time_boot_ms" in d:
        return d["time_boot_ms"] * 1e-3
    return None


def is_offboard_mode(autopilot: int, custom_mode: int, base_mode: int) -> bool:
    """Whether a HEARTBEAT reports the mode in which a companion computer flies: PX4 OFFBOARD (custom main mode 6),
    ArduPilot GUIDED / GUIDED_NOGPS (custom modes 4, 20); needs MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (1)."""
    if not base_mode & 1:
        return False
    if autopilot == 12:
        return (custom_mode >> 16) & 0xFF == PX4_MAIN_MODE_OFFBOARD
    if autopilot == 3:
        return custom_mode in ARDUPILOT_COPTER_GUIDED
    return False


# ---------------------------------------------------------------------------------------------------------------
# pass 1: read and inventory


@dataclass
class SystemInfo:
    """One MAVLink source (system id, component id) seen in the log."""

    sysid: int
    compid: int
    messages: dict[str, int] = field(default_factory=dict)
    heartbeat: tuple[int, int] | None = None  # (MAV_TYPE, MAV_AUTOPILOT) of its last HEARTBEAT
    vt_first: float = math.inf  # vehicle time span of its timed messages, s
    vt_last: float = -math.inf
    lt_first: float = math.inf  # logger time span, s since the epoch
    lt_last: float = -math.inf

    @property
    def count(self) -> int:
        return sum(self.messages.values())


@dataclass
class Event:
    """One entry of the replay stream, in log order. kind: "m" (measurement), "sp" (setpoint sent to the
    autopilot), "at" (the autopilot's ATTITUDE_TARGET), "mode" (offboard flag changed).

    sysid: sender; vt: vehicle/sender time field (s) or None; lt: logger time (s); payload: the record."""

    kind: str
    sysid: int
    vt: float | None
    lt: float
    payload: Any


@dataclass
class Scan:
    """Result of pass 1: systems, events, reader counters, autopilot identity and mode history."""

    systems: dict[tuple[int, int], SystemInfo]
    events: list[Event]
    reader_stats: dict[str, Any]
    autopilot_sysid: int | None
    autopilot: int | None
    mav_type: int | None
    offboard_heartbeats: int
    heartbeats: int
    mode_changes: list[tuple[float, bool]]  # (logger time, offboard?) whenever the autopilot's mode flag changes
    setpoint_targets: dict[str, int]


def scan(messages: Iterable[tuple[float, Any]]) -> Scan:
    """Pass 1 over ``(logger_time_s, message)`` pairs (see module docstring)."""
    systems: dict[tuple[int, int], SystemInfo] = {}
    events: list[Event] = []
    decoder = TelemetryDecoder(system=None, use_attitude_quaternion=False, use_odometry=False)
    ap_sysid: int | None = None
    ap_kind: int | None = None
    mav_type: int | None = None
    telemetry_sysid: int | None = None
    hb_total = 0
    hb_offboard = 0
    last_off: bool | None = None
    mode_changes: list[tuple[float, bool]] = []
    sp_targets: dict[str, int] = {}
    has_attitude: dict[int, bool] = {}
    for lt, msg in messages:
        kind = msg.get_type()
        sid, cid = msg.get_srcSystem(), msg.get_srcComponent()
        info = systems.get((sid, cid))
        if info is None:
            info = systems[(sid, cid)] = SystemInfo(sid, cid)
        info.messages[kind] = info.messages.get(kind, 0) + 1
        if lt < info.lt_first:
            info.lt_first = lt
        if lt > info.lt_last:
            info.lt_last = lt
        vt = vehicle_time_of(msg)
        if vt is not None:
            if vt < info.vt_first:
                info.vt_first = vt
            if vt > info.vt_last:
                info.vt_last = vt
        if kind == "HEARTBEAT":
            info.heartbeat = (msg.type, msg.autopilot)
            if msg.autopilot != 8 and msg.type not in NON_VEHICLE_TYPES:
                if ap_sysid is None:
                    ap_sysid, ap_kind, mav_type = sid, msg.autopilot, msg.type
                if sid == ap_sysid:
                    hb_total += 1
                    off = is_offboard_mode(msg.autopilot, msg.custom_mode, msg.base_mode)
                    hb_offboard += off
                    if off != last_off:
                        mode_changes.append((lt, off))
                        events.append(Event("mode", sid, None, lt, off))
                        last_off = off
            continue
        if kind in TELEMETRY_TYPES:
            if kind == "ATTITUDE":
                has_attitude[sid] = True
                if telemetry_sysid is None:
                    telemetry_sysid = sid
            m = decoder.decode(msg)
            if m is not None:
                events.append(Event("m", sid, m.t, lt, m))
            continue
        if kind in SETPOINT_TYPES:
            sp = decode_setpoint(msg)
            if sp is not None:
                tgt = msg.target_system
                sp_targets[kind] = sp_targets.get(kind, 0) + 1
                events.append(Event("sp", tgt, vt, lt, (sp, msg)))
            continue
        if kind == "ATTITUDE_TARGET":
            events.append(Event("at", sid, vt, lt, (tuple(float(v) for v in msg.q), float(msg.thrust))))
    if ap_sysid is None:
        ap_sysid = telemetry_sysid
    return Scan(systems, events, {}, ap_sysid, ap_kind, mav_type, hb_offboard, hb_total, mode_changes, sp_targets)


def inventory(sc: Scan) -> dict[str, Any]:
    """What was found in the log (the ``log`` block of metrics.json) and what is missing for the replay."""
    ap = sc.autopilot_sysid
    msg_counts: dict[str, int] = {}
    systems = []
    for (sid, cid), info in sorted(sc.systems.items()):
        for k, v in info.messages.items():
            if sid == ap:
                msg_counts[k] = msg_counts.get(k, 0) + v
        span = info.vt_last - info.vt_first if info.vt_last > info.vt_first else None
        lspan = info.lt_last - info.lt_first if info.lt_last > info.lt_first else None
        hb = info.heartbeat
        systems.append({
            "sysid": sid, "compid": cid, "messages": info.count,
            "type": None if hb is None else MAV_TYPE_NAMES.get(hb[0], f"type {hb[0]}"),
            "autopilot": None if hb is None else MAV_AUTOPILOT_NAMES.get(hb[1], f"autopilot {hb[1]}"),
            "logger_span_s": lspan, "vehicle_time_span_s": span,
            "rates_hz": {k: (v - 1) / span for k, v in sorted(info.messages.items()) if span and v > 1
                         and k in TELEMETRY_TYPES | {"ATTITUDE_TARGET", *SETPOINT_TYPES}},
        })
    by_kind = {k: 0 for k in ("PositionVelocity", "Attitude", "Imu", "LoadAngle")}
    load_system = False
    for e in sc.events:
        if e.kind == "m" and e.sysid == ap:
            by_kind[type(e.payload).__name__] += 1
    for (sid, _), info in sc.systems.items():
        if sid != ap and "GLOBAL_POSITION_INT" in info.messages and "HEARTBEAT" not in info.messages:
            load_system = True
    sp_to_ap = sum(1 for e in sc.events if e.kind == "sp" and (e.sysid == ap or e.sysid == 0))
    mt = sc.mav_type
    vehicle_class = ("unknown" if mt is None else "multirotor" if mt in MULTIROTOR_TYPES
                     else "fixed wing" if mt in FIXED_WING_TYPES else "other")
    missing: list[str] = []
    if ap is None:
        missing.append("no autopilot found: no HEARTBEAT from a vehicle and no ATTITUDE telemetry")
    if sc.heartbeats == 0 and ap is not None:
        missing.append("no HEARTBEAT from the autopilot: flavour, vehicle type and flight mode unknown "
                       f"(system {ap} assumed from its ATTITUDE telemetry)")
    if vehicle_class == "fixed wing":
        missing.append(f"vehicle type is {MAV_TYPE_NAMES.get(mt, mt)} (fixed wing): the slung-load model, "
                       "estimator and controller are for multirotors; not replayed")
    elif vehicle_class == "other":
        missing.append(f"vehicle type is {MAV_TYPE_NAMES.get(mt, mt)}: not a multirotor; not replayed")
    if by_kind["Attitude"] == 0:
        missing.append("no ATTITUDE telemetry from the autopilot: the estimator cannot run")
    if by_kind["PositionVelocity"] == 0:
        missing.append("no local position (LOCAL_POSITION_NED / ODOMETRY): the vehicle's position and velocity, "
                       "hence the flat outputs, cannot be estimated; not replayed")
    if by_kind["LoadAngle"] == 0:
        if by_kind["Imu"] == 0:
            missing.append("no cable-angle sensor and no IMU telemetry: the swing is unobservable")
        else:
            missing.append(f"no cable-angle sensor (DEBUG_VECT {LOAD_ANGLE_NAME!r}): the swing is estimated from "
                           "the accelerometer only; whether a load is attached at all cannot be told from the log")
    return {
        "systems": systems,
        "autopilot_sysid": ap,
        "autopilot": None if sc.autopilot is None else MAV_AUTOPILOT_NAMES.get(sc.autopilot, f"{sc.autopilot}"),
        "vehicle_type": None if mt is None else MAV_TYPE_NAMES.get(mt, f"type {mt}"),
        "vehicle_class": vehicle_class,
        "message_counts": dict(sorted(msg_counts.items())),
        "measurements": by_kind,
        "has_load_sensor": by_kind["LoadAngle"] > 0,
        "has_load_system": load_system,
        "has_local_position": by_kind["PositionVelocity"] > 0,
        "has_imu": by_kind["Imu"] > 0,
        "heartbeats": sc.heartbeats,
        "offboard_heartbeats": sc.offboard_heartbeats,
        "setpoints_to_autopilot": sp_to_ap,
        "setpoint_messages": dict(sc.setpoint_targets),
        "has_offboard_segment": sp_to_ap > 0 or sc.offboard_heartbeats > 0,
        "missing": missing,
    }


def replayable(inv: dict[str, Any]) -> tuple[bool, list[str]]:
    """Whether the estimator can run on the log, and the reasons when it cannot."""
    reasons = []
    if inv["autopilot_sysid"] is None:
        reasons.append("no autopilot telemetry")
    if inv["vehicle_class"] in ("fixed wing", "other"):
        reasons.append(f"vehicle type {inv['vehicle_type']} is not a multirotor")
    if not inv["measurements"]["Attitude"]:
        reasons.append("no ATTITUDE telemetry")
    if not inv["has_local_position"]:
        reasons.append("no local position")
    if not inv["has_load_sensor"] and not inv["has_imu"]:
        reasons.append("neither a cable-angle sensor nor an IMU")
    return not reasons, reasons


# ---------------------------------------------------------------------------------------------------------------
# pass 2: replay


@dataclass(frozen=True)
class ReferenceSpec:
    """The reference a logged flight used: scenario name and the controller time (s) at which its t = 0 fell."""

    scenario: str
    start: float


@dataclass(frozen=True)
class ReplayConfig:
    """How to replay. vehicle: the controller's nominal vehicle; t_from / t_to: vehicle-time window (s) or None;
    rate_hz: tick rate where no setpoints are logged (and the estimator's step when the log does not say);
    estimator: estimator kind; load_sensor: None = use one when the log has it; reference: see
    :class:`ReferenceSpec`; switching / epsilon: the controller's switching function; output / mask: None =
    from the logged setpoints; flavour: None = from the HEARTBEAT; delay_s: the estimator's fusion horizon."""

    vehicle: Vehicle = field(default_factory=Vehicle)
    t_from: float | None = None
    t_to: float | None = None
    rate_hz: float = 250.0
    estimator: str = "kf"
    load_sensor: bool | None = None
    reference: ReferenceSpec | None = None
    switching: str = "smooth"
    epsilon: float = 1.0
    output: str | None = None
    mask: str | None = None
    flavour: str | None = None
    hover_thrust_norm: float | None = None
    delay_s: float = 0.012


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
        "t", "logger_t", "tick_source", *EST_COLUMNS, "meas_alpha_x", "meas_alpha_y",
        "pos_x", "pos_y", "pos_z",
        "Fx_ref", "Fy_ref", "z_ref", "psi_ref", "cmd_thrust", "cmd_tau_phi", "cmd_tau_theta", "cmd_tau_psi",
        *("sp_" + c for c in sp), *("log_" + c for c in sp), "ap_q_w", "ap_q_x", "ap_q_y", "ap_q_z", "ap_thrust",
        "offboard",
    )


@dataclass
class ReplayResult:
    """The replayed run: ``data[k, col[name]]`` per tick, the column names and the metrics dictionary."""

    data: np.ndarray
    columns: tuple[str, ...]
    metrics: dict[str, Any]
    output: str

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.columns.index(name)]


def initial_guess(vehicle: Vehicle, pv: PositionVelocity | None, att: Attitude | None,
                  load: LoadAngle | None) -> ControlState:
    """The estimator's prior from the first measurements: position / velocity, attitude, swing (0 without a
    cable-angle sensor); every rate not measured is 0."""
    k = flat_constants(vehicle)
    x = y = z = vx = vy = vz = 0.0
    if pv is not None:
        x, y, z, vx, vy, vz = pv.x, pv.y, pv.z, pv.vx, pv.vy, pv.vz
    phi = theta = psi = 0.0
    if att is not None:
        phi, theta, psi = att.phi, att.theta, att.psi
    ax = ay = 0.0
    if load is not None:
        ax, ay = load.alpha_x, load.alpha_y
    nx, ny, nxd, nyd = world_tilt(phi, theta, psi, 0.0, 0.0, 0.0)
    return ControlState(flat_chain(k, x, vx, ay, 0.0, nx, nxd), flat_chain(k, y, vy, ax, 0.0, ny, nyd),
                        z, vz, phi, theta, psi, 0.0, 0.0, 0.0, ax, ay, 0.0, 0.0)


def _quat_angle(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Rotation angle (rad) between two unit quaternions (sign-insensitive)."""
    d = abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3])
    return 2.0 * math.acos(min(1.0, d))


def _sp_fields(sp: Any) -> tuple[float, ...]:
    if isinstance(sp, AttitudeTarget):
        return (*sp.q, sp.roll_rate, sp.pitch_rate, sp.yaw_rate, sp.thrust)
    return tuple(sp)


def replay(sc: Scan, inv: dict[str, Any], config: ReplayConfig,
           progress: Callable[[float], None] | None = None) -> ReplayResult:
    """Pass 2 (see module docstring). The log must be :func:`replayable`."""
    from estimators.factory import make_estimator
    from offboard import smc
    from offboard.command_mapping import AutopilotModel, CommandMapper, MappingConfig

    ap = inv["autopilot_sysid"]
    vehicle = config.vehicle
    load_sensor = inv["has_load_sensor"] if config.load_sensor is None else config.load_sensor
    events = [e for e in sc.events if e.kind != "m" or e.sysid == ap]
    sp_events = [e for e in events if e.kind == "sp" and (e.sysid == ap or e.sysid == 0)]
    output = config.output or ("actuator" if any(isinstance(e.payload[0], ActuatorTarget) for e in sp_events)
                               else "attitude")
    sp_events = [e for e in sp_events if isinstance(e.payload[0], AttitudeTarget if output == "attitude"
                                                    else ActuatorTarget)]
    logged_ticks = len(sp_events) > 0
    rate = config.rate_hz
    if logged_ticks and len(sp_events) > 2:
        ts = [e.vt for e in sp_events if e.vt is not None]
        if len(ts) > 2:
            dts = np.diff(np.asarray(ts))
            dts = dts[dts > 0]
            if len(dts):
                rate = float(1.0 / np.median(dts))
    estimator = make_estimator(config.estimator, vehicle, load_sensor=load_sensor, rate_hz=rate,
                               delay_s=config.delay_s)
    scenario = None
    ref_start = 0.0
    if config.reference is not None and logged_ticks:
        from offboard.scenarios import make_scenario

        scenario = make_scenario(config.reference.scenario)
        ref_start = config.reference.start
    params = smc.ControllerParams.for_vehicle(vehicle, switching=config.switching, epsilon=config.epsilon)
    mask = config.mask
    if mask is None:
        masks = {e.payload[0].type_mask for e in sp_events if isinstance(e.payload[0], AttitudeTarget)}
        from offboard.link.setpoints import MASKS

        inverse = {v: k for k, v in MASKS.items()}
        mask = inverse.get(next(iter(masks)), "attitude") if len(masks) == 1 else "attitude"
    flavour = config.flavour or (inv["autopilot"] if inv["autopilot"] in ("px4", "ardupilot") else "px4")
    mapper = CommandMapper(vehicle, MappingConfig(output=output, mask=mask),
                           AutopilotModel(flavour=flavour, hover_thrust_norm=config.hover_thrust_norm))
    memory = smc.ControllerMemory()

    cols = columns_for(output)
    nsp = len(SP_ATT if output == "attitude" else SP_ACT)
    nan = math.nan
    nan_sp = (nan,) * nsp
    rows: list[tuple[float, ...]] = []
    t_from = -math.inf if config.t_from is None else config.t_from
    t_to = math.inf if config.t_to is None else config.t_to

    first_pv = next((e.payload for e in events if e.kind == "m" and isinstance(e.payload, PositionVelocity)
                     and e.payload.t >= t_from), None)
    first_att = next((e.payload for e in events if e.kind == "m" and isinstance(e.payload, Attitude)
                      and e.payload.t >= t_from), None)
    first_load = next((e.payload for e in events if e.kind == "m" and isinstance(e.payload, LoadAngle)
                       and e.payload.t >= t_from), None) if load_sensor else None
    initialized = False
    t_init = 0.0
    last_load = (nan, nan)
    last_pos = (nan, nan, nan)
    last_at: tuple[float, ...] = (nan,) * 5
    offboard = 0.0
    vnow = -math.inf
    next_tick = math.nan
    period = 1.0 / rate
    n_ev = len(events)
    next_prog = 0
    cmp_angle: list[float] = []
    cmp_fields: list[tuple[float, ...]] = []
    ap_angle: list[float] = []
    last_t = -math.inf

    def estimate_row(t: float, lt: float, src: float) -> tuple[ControlState, tuple[float, ...]]:
        est = estimator.estimate(t)
        return est, (t, lt, src, *est.fx, *est.fy, *est[2:], *last_load, *last_pos)

    for idx, e in enumerate(events):
        if progress is not None and idx >= next_prog:
            progress(idx / n_ev)
            next_prog = idx + 2000
        kind = e.kind
        if kind == "m":
            m = e.payload
            if m.t < t_from or m.t > t_to:
                continue
            if not initialized:
                t_init = m.t
                estimator.initialize(t_init, initial_guess(vehicle, first_pv, first_att, first_load))
                initialized = True
                next_tick = t_init + period
            if not logged_ticks:
                # grid ticks: run every tick that the newest sample time has passed, before this sample
                if m.t > vnow:
                    vnow = m.t
                while next_tick <= vnow:
                    _, row = estimate_row(next_tick, e.lt, 0.0)
                    rows.append((*row, nan, nan, nan, nan, nan, nan, nan, nan, *nan_sp, *nan_sp, *last_at, offboard))
                    next_tick += period
            estimator.push(m)
            if isinstance(m, LoadAngle):
                last_load = (m.alpha_x, m.alpha_y)
            elif isinstance(m, PositionVelocity):
                last_pos = (m.x, m.y, m.z)
        elif kind == "mode":
            offboard = 1.0 if e.payload else 0.0
        elif kind == "at":
            q, thr = e.payload
            last_at = (*q, thr)
        elif kind == "sp" and logged_ticks and initialized:
            sp_logged = e.payload[0]
            if not isinstance(sp_logged, AttitudeTarget if output == "attitude" else ActuatorTarget):
                continue
            t = e.vt if e.vt is not None else last_t
            if t is None or t < t_init or t < t_from or t > t_to or t <= last_t:
                continue
            last_t = t
            est, row = estimate_row(t, e.lt, 1.0)
            logged = _sp_fields(sp_logged)
            if scenario is not None:
                ref = scenario.reference.sample(t - ref_start)
                cmd, memory = smc.step(t, est, ref.fx, ref.fy, ref.z, ref.psi, memory, params)
                sp = mapper.map(t, cmd, est)
                estimator.push_command(t, cmd.thrust, (cmd.tau_phi, cmd.tau_theta, cmd.tau_psi))
                recomputed = _sp_fields(sp)
                refs = (ref.fx[0], ref.fy[0], ref.z[0], ref.psi[0])
                cmds = (cmd.thrust, cmd.tau_phi, cmd.tau_theta, cmd.tau_psi)
                if output == "attitude":
                    cmp_angle.append(_quat_angle(recomputed[:4], logged[:4]))
                    cmp_fields.append(tuple(abs(a - b) for a, b in zip(recomputed[4:], logged[4:])))
                else:
                    cmp_fields.append(tuple(abs(a - b) for a, b in zip(recomputed, logged)))
            else:
                recomputed = nan_sp
                refs = (nan,) * 4
                cmds = (nan,) * 4
            if output == "attitude" and math.isfinite(last_at[0]):
                ap_angle.append(_quat_angle(last_at[:4], logged[:4]))
            rows.append((*row, *refs, *cmds, *recomputed, *logged, *last_at, offboard))
    if progress is not None:
        progress(1.0)
    data = np.array(rows, dtype=float) if rows else np.zeros((0, len(cols)))
    metrics = _metrics(data, cols, inv, estimator, output, logged_ticks, scenario is not None, cmp_angle,
                       cmp_fields, ap_angle, config, rate, load_sensor, mapper)
    return ReplayResult(data, cols, metrics, output)


def _stats(x: np.ndarray) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return {"max": None, "rms": None, "p99": None}
    return {"max": float(np.max(np.abs(x))), "rms": float(np.sqrt(np.mean(x * x))),
            "p99": float(np.percentile(np.abs(x), 99))}


def _metrics(data: np.ndarray, cols: tuple[str, ...], inv: dict[str, Any], estimator: Any, output: str,
             logged_ticks: bool, controller_ran: bool, cmp_angle: list[float], cmp_fields: list[tuple[float, ...]],
             ap_angle: list[float], config: ReplayConfig, rate: float, load_sensor: bool,
             mapper: Any) -> dict[str, Any]:
    c = {n: i for i, n in enumerate(cols)}
    col = lambda n: data[:, c[n]]  # noqa: E731 - short accessor
    n = len(data)
    t = col("t") if n else np.zeros(0)
    est: dict[str, Any] = {
        "ticks": n,
        "tick_source": "logged setpoints" if logged_ticks else f"grid at {rate:g} Hz",
        "rate_hz": rate,
        "estimator": config.estimator,
        "load_sensor_used": load_sensor,
        "vehicle_time_span_s": [float(t[0]), float(t[-1])] if n else None,
        "estimator_stats": estimator.stats(),
        "all_finite": bool(np.all(np.isfinite(data[:, 3:3 + len(EST_COLUMNS)]))) if n else True,
    }
    if n:
        ax, ay = col("alpha_x"), col("alpha_y")
        alpha = np.sqrt(ax * ax + ay * ay)
        est["swing_max_rad"] = float(np.max(alpha))
        est["swing_rms_rad"] = float(np.sqrt(np.mean(alpha * alpha)))
        if load_sensor:
            est["alpha_x_vs_sensor"] = _stats(ax - col("meas_alpha_x"))
            est["alpha_y_vs_sensor"] = _stats(ay - col("meas_alpha_y"))
    tracking: dict[str, Any] | None = None
    agreement: dict[str, Any] | None = None
    if controller_ran and n:
        m = col("tick_source") == 1.0
        tracking = {"note": "errors of the ESTIMATED flat outputs, height and heading against the reference"}
        for name, a, b in (("e_Fx", "Fx", "Fx_ref"), ("e_Fy", "Fy", "Fy_ref"), ("e_z", "z", "z_ref")):
            tracking[name] = _stats((col(a) - col(b))[m])
        tracking["e_psi"] = _stats(np.remainder(col("psi") - col("psi_ref") + math.pi, 2 * math.pi)[m] - math.pi)
        agreement = {"ticks_compared": len(cmp_fields), "mapper_fallbacks": mapper.fallbacks}
        if cmp_fields:
            f = np.asarray(cmp_fields)
            names = SP_ATT[4:] if output == "attitude" else SP_ACT
            for i, nm in enumerate(names):
                agreement[nm] = _stats(f[:, i])
            if output == "attitude":
                agreement["attitude_angle_rad"] = _stats(np.asarray(cmp_angle))
            worst = max(float(np.max(f)), max(cmp_angle) if cmp_angle else 0.0)
            agreement["max_abs_difference"] = worst
            agreement["identical_to_1e-9"] = worst <= 1e-9
    if ap_angle:
        agreement = agreement or {}
        agreement["logged_vs_autopilot_attitude_target_rad"] = _stats(np.asarray(ap_angle))
    return {
        "log": inv,
        "estimation": est,
        "tracking": tracking,
        "setpoint_agreement": agreement,
        "config": {
            "vehicle": config.vehicle.name,
            "from_s": config.t_from, "to_s": config.t_to, "output": output, "switching": config.switching,
            "epsilon": config.epsilon,
            "reference": None if config.reference is None else {"scenario": config.reference.scenario,
                                                                 "start_s": config.reference.start},
        },
    }


__all__ = [
    "EST_COLUMNS", "Event", "ReferenceSpec", "ReplayConfig", "ReplayResult", "Scan", "SystemInfo", "columns_for",
    "initial_guess", "inventory", "is_offboard_mode", "replay", "replayable", "scan", "vehicle_time_of",
]
