"""On-board flight logs -> the replay's records: PX4 ULog (``.ulg``, read with pyulog) and ArduPilot DataFlash
(``.bin``, read with pymavlink's DFReader), turned into the same :class:`offboard.logs.log_inventory.Scan` a tlog gives
(measurement records in the model frame, armed / landed / mode events), so that the same inventory, segments and
estimator run on them.

Both logs are written by the autopilot itself, on its own clock: every time here is the vehicle's time since boot
(s), and the logger time of an event is that same time. Frames: NED / FRD in the logs, converted with
``estimators.model.frames`` only; degrees (DataFlash ATT) become radians here.

PX4 ULog topics used
    ``vehicle_attitude`` (quaternion ``q``) with the body rates of ``vehicle_angular_velocity`` (``xyz``; older
    logs: ``vehicle_attitude.rollspeed``...) -> Attitude; ``vehicle_local_position`` (``x, y, z, vx, vy, vz``) ->
    PositionVelocity; ``sensor_combined`` (``gyro_rad``, ``accelerometer_m_s2``) -> Imu; ``vehicle_status``
    (``arming_state`` 2 = armed, ``nav_state`` names) -> armed and mode; ``vehicle_land_detected`` (``landed``) ->
    landed state; ``debug_vect`` named ``LOADANG`` (a cable-angle sensor's DEBUG_VECT as PX4 received it, x / y
    the swing in the North-Down / East-Down plane, rad, timed at its reception: PX4 keeps no sensor time for it)
    -> LoadAngle. PX4 logs ``debug_vect`` only with the debug bit of ``SDLOG_PROFILE`` (32), which
    ``sim_bridge.sitl.px4_hil.hil_params`` sets; a log without it has no cable angle, and its swing is estimated
    from the IMU, as on a vehicle without the sensor.
ArduPilot DataFlash messages used
    ``ATT`` (Roll, Pitch, Yaw in degrees) with the body rates of ``RATE`` (``R, P, Y``: the attitude controller's
    achieved rates, the AHRS's bias-corrected gyro, deg/s; centideg/s before ArduPilot 3.4, told apart by their
    ratio to the IMU gyro) where the log has it (at most
    :data:`DF_RATE_MAX_AGE_S` old), else the first ``IMU``'s raw gyro -> Attitude; the first IMU (``GyrX``..
    rad/s, ``AccX``.. m/s^2) -> Imu; the EKF's position and velocity (``XKF1`` core 0, else ``NKF1``, else
    ``EKF1``: ``PN, PE, PD, VN, VE, VD``) -> PositionVelocity; ``EV`` (10 armed, 11 disarmed, 18 land complete,
    28 not landed) and ``ARM`` -> armed and landed state; ``MODE`` -> mode names (the vehicle's own table);
    ``MSG`` names the firmware (ArduCopter, ArduPlane, ArduRover, ArduSub); ``SLUP`` (ArduPilot SITL's slung
    payload, ``libraries/SITL/SIM_SlungPayload.cpp``: ``PN, PE, PD`` the payload's offset from the vehicle, m NED;
    ``Land`` 1 when the payload rests on the ground; ``Tens`` 0 slack .. 1 taut) -> "payload" events, the swing's
    truth (samples with the payload landed or the line slack are left out: the swing angle is then undefined).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from estimators.model.frames import (
    frd_to_model_body,
    ned_euler_to_model,
    ned_quaternion_to_model,
    ned_to_model_vector,
    quaternion_to_euler,
)
from estimators.model.measurements import Attitude, Imu, PositionVelocity
from offboard.flight.link.telemetry import LOAD_ANGLE_NAME, load_angle_from_ned, plausible_load_angles
from offboard.logs.flight_modes import MAV_AUTOPILOT_ARDUPILOT, MAV_AUTOPILOT_PX4
from offboard.logs.log_inventory import Event, Scan, SystemInfo

#: the system id given to the autopilot of an on-board log (it has no MAVLink identity of its own)
LOG_SYSID = 1
#: PX4 vehicle_status.nav_state names (uORB msg/VehicleStatus.msg)
PX4_NAV_STATES = {
    0: "MANUAL",
    1: "ALTCTL",
    2: "POSCTL",
    3: "AUTO_MISSION",
    4: "AUTO_LOITER",
    5: "AUTO_RTL",
    10: "ACRO",
    12: "DESCEND",
    13: "TERMINATION",
    14: "OFFBOARD",
    15: "STAB",
    17: "AUTO_TAKEOFF",
    18: "AUTO_LAND",
    19: "AUTO_FOLLOW_TARGET",
    20: "AUTO_PRECLAND",
    21: "ORBIT",
    22: "AUTO_VTOL_TAKEOFF",
}
PX4_NAV_STATE_OFFBOARD = 14
PX4_ARMING_STATE_ARMED = 2
#: PX4 vehicle_status.vehicle_type -> MAV_TYPE (rotary wing -> quadrotor, fixed wing, rover)
PX4_VEHICLE_TYPES = {1: 2, 2: 1, 3: 10}
#: DataFlash MSG firmware names -> MAV_TYPE of the vehicle (for ArduPilot's mode tables)
ARDUPILOT_FIRMWARE_TYPES = {"copter": 2, "plane": 1, "rover": 10, "sub": 12, "heli": 4}
DF_EV_ARMED, DF_EV_DISARMED, DF_EV_LAND_COMPLETE, DF_EV_NOT_LANDED = 10, 11, 18, 28
#: messages whose time field is the vehicle's time since boot and that come often: the clock of events without one
_DF_CLOCK_SOURCES = frozenset({"IMU", "ATT", "XKF1", "NKF1", "EKF1", "CTUN", "RATE"})
#: the DataFlash messages read (the others are skipped unparsed, and not counted in ``message_counts``)
DF_TYPES = ["IMU", "ATT", "XKF1", "NKF1", "EKF1", "EV", "ARM", "MODE", "MSG", "CTUN", "RATE", "SLUP"]
#: a RATE record older than this (s) is not used for ATT's body rates (the IMU gyro is, as in a log without RATE)
DF_RATE_MAX_AGE_S = 0.5
#: RATE's rates more than this many times the IMU gyro's (both in deg/s, summed over the log) are centidegrees/s:
#: the true ratio is 1 or 100 (the AHRS's gyro is the IMU's less a small bias), so 10 splits them with a wide margin
RATE_CENTIDEG_RATIO = 10.0
ULOG_TOPICS = (
    "vehicle_attitude",
    "vehicle_angular_velocity",
    "vehicle_local_position",
    "sensor_combined",
    "vehicle_status",
    "vehicle_land_detected",
    "debug_vect",
)


def log_format_of(path: Path) -> str:
    """``"ulog"``, ``"dataflash"`` or ``"tlog"`` by the file's first bytes (ULog's magic ``ULog\\x01\\x12\\x35``,
    DataFlash's ``0xA3 0x95`` header), else by its extension; a tlog otherwise."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError:
        return "tlog"
    if head.startswith(b"ULog\x01\x12\x35"):
        return "ulog"
    if head[:2] == b"\xa3\x95":
        return "dataflash"
    ext = path.suffix.lower()
    return {".ulg": "ulog", ".bin": "dataflash"}.get(ext, "tlog")


class _Builder:
    """Collects (time, order, Event) entries and per-topic counts, then makes the :class:`Scan`."""

    def __init__(self, fmt: str) -> None:
        self.entries: list[tuple[float, int, Event]] = []
        self.info = SystemInfo(LOG_SYSID, 1)
        self.fmt = fmt
        self.notes: list[str] = []
        self.sources: dict[str, str] = {}

    def count(self, name: str, n: int, t0: float | None = None, t1: float | None = None) -> None:
        if n <= 0:
            return
        self.info.messages[name] = self.info.messages.get(name, 0) + n
        if t0 is not None and t1 is not None and t1 > t0 > 0.0:
            self.info.spans[name] = [t0, t1]
            self.info.vt_first = min(self.info.vt_first, t0)
            self.info.vt_last = max(self.info.vt_last, t1)
            self.info.lt_first, self.info.lt_last = self.info.vt_first, self.info.vt_last

    def count_times(self, name: str, ts: Sequence[float]) -> None:
        """:meth:`count` of a topic's samples at the sorted times ``ts`` (s), their span with them."""
        self.count(name, len(ts), ts[0] if ts else None, ts[-1] if ts else None)

    def add(self, kind: str, t: float, payload: Any, order: int = 1) -> None:
        self.entries.append((t, order, Event(kind, LOG_SYSID, t, t, payload)))

    def add_measurement(self, t: float, record: Any) -> None:
        """A measurement record at ``t``, unless a field of it is not finite (a damaged sample is left out)."""
        if math.isfinite(sum(record)):
            self.add("m", t, record)

    def scan(self, autopilot: int, mav_type: int | None) -> Scan:
        self.entries.sort(key=lambda e: (e[0], e[1]))
        events = [e for _, _, e in self.entries]
        modes = [(e.lt, bool(e.payload)) for e in events if e.kind == "mode"]
        if mav_type is not None:
            self.info.heartbeat = (mav_type, autopilot)
        n_status = sum(1 for e in events if e.kind in ("armed", "modename"))
        return Scan(
            {(LOG_SYSID, 1): self.info},
            events,
            {},
            LOG_SYSID,
            autopilot,
            mav_type,
            sum(1 for _, off in modes if off),
            max(n_status, 1) if mav_type is not None else 0,
            modes,
            {},
            self.fmt,
            self.notes,
            self.sources,
        )


# ---------------------------------------------------------------------------------------------------------------
# PX4 ULog


def _topic(ulog: Any, name: str) -> dict[str, Any] | None:
    """The first instance's data (field -> numpy array) of a ULog topic, or None."""
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0:
            return d.data
    return None


def _vec(data: dict[str, Any], base: str) -> tuple[Any, Any, Any] | None:
    """Fields ``base[0..2]`` (ULog's array fields) or ``base`` + ``x/y/z`` of a topic, or None."""
    if f"{base}[0]" in data:
        return data[f"{base}[0]"], data[f"{base}[1]"], data[f"{base}[2]"]
    return None


def _seconds(data: dict[str, Any]) -> list[float]:
    """A topic's sample times, s (ULog's ``timestamp`` is in microseconds)."""
    return (data["timestamp"] * 1e-6).tolist()


def scan_ulog(path: Path) -> Scan:
    """A PX4 ULog as a :class:`Scan` (see module docstring). UserError when pyulog cannot read it."""
    try:
        from pyulog import ULog

        ulog = ULog(str(path), list(ULOG_TOPICS), parse_header_only=False)
    except Exception as exc:  # pyulog raises plain Exceptions of many kinds on a damaged file
        raise UserError(f"{path}: not a readable ULog ({type(exc).__name__}: {exc})") from None
    b = _Builder("ulog")
    att = _topic(ulog, "vehicle_attitude")
    rates_t: list[float] = []
    rates: list[tuple[float, float, float]] = []
    avel = _topic(ulog, "vehicle_angular_velocity")
    if avel is not None and _vec(avel, "xyz") is not None:
        x, y, z = _vec(avel, "xyz")  # type: ignore[misc]
        rates_t = _seconds(avel)
        rates = list(zip(x.tolist(), y.tolist(), z.tolist()))
    elif att is not None and "rollspeed" in att:
        rates_t = _seconds(att)
        rates = list(zip(att["rollspeed"].tolist(), att["pitchspeed"].tolist(), att["yawspeed"].tolist()))
    imu = _topic(ulog, "sensor_combined")
    if imu is not None:
        g = _vec(imu, "gyro_rad")
        a = _vec(imu, "accelerometer_m_s2")
        if g is not None and a is not None:
            ts = _seconds(imu)
            if not rates:  # the gyro as the body rates when the log has no rate topic
                rates_t, rates = ts, list(zip(g[0].tolist(), g[1].tolist(), g[2].tolist()))
            cols = [v.tolist() for v in (*a, *g)]
            for i, t in enumerate(ts):
                ax, ay, az = frd_to_model_body(cols[0][i], cols[1][i], cols[2][i])
                gx, gy, gz = frd_to_model_body(cols[3][i], cols[4][i], cols[5][i])
                m = Imu(t, ax, ay, az, gx, gy, gz)
                b.add_measurement(t, m)
            b.count_times("sensor_combined", ts)
    if att is not None and "q[0]" in att:
        ts = _seconds(att)
        q = [att[f"q[{i}]"].tolist() for i in range(4)]
        for i, t in enumerate(ts):
            j = bisect.bisect_right(rates_t, t) - 1
            p_, q_, r_ = rates[j] if j >= 0 else (0.0, 0.0, 0.0)
            try:
                phi, theta, psi = quaternion_to_euler(*ned_quaternion_to_model(q[0][i], q[1][i], q[2][i], q[3][i]))
            except ValueError:
                continue
            p, qq, r = frd_to_model_body(p_, q_, r_)
            m = Attitude(t, phi, theta, psi, p, qq, r)
            b.add_measurement(t, m)
        b.count_times("vehicle_attitude", ts)
    lp = _topic(ulog, "vehicle_local_position")
    if lp is not None:
        ts = _seconds(lp)
        cols = [lp[k].tolist() for k in ("x", "y", "z", "vx", "vy", "vz")]
        valid = lp["xy_valid"].tolist() if "xy_valid" in lp else [1] * len(ts)
        z_valid = lp["z_valid"].tolist() if "z_valid" in lp else [0] * len(ts)
        for i, t in enumerate(ts):
            if not valid[i]:
                if z_valid[i]:  # the height alone (no GPS): kept for a replay of what can be estimated
                    _, _, z = ned_to_model_vector(0.0, 0.0, cols[2][i])
                    _, _, vz = ned_to_model_vector(0.0, 0.0, cols[5][i])
                    if math.isfinite(z) and math.isfinite(vz):
                        b.add("height", t, (t, z, vz))
                continue
            x, y, z = ned_to_model_vector(cols[0][i], cols[1][i], cols[2][i])
            vx, vy, vz = ned_to_model_vector(cols[3][i], cols[4][i], cols[5][i])
            m = PositionVelocity(t, x, y, z, vx, vy, vz)
            b.add_measurement(t, m)
        b.count_times("vehicle_local_position", ts)
    _scan_ulog_load_angles(ulog, b)
    mav_type: int | None = None
    st = _topic(ulog, "vehicle_status")
    if st is not None:
        ts = _seconds(st)
        armed_col = st["arming_state"].tolist() if "arming_state" in st else []
        nav = st["nav_state"].tolist() if "nav_state" in st else []
        if "vehicle_type" in st and len(st["vehicle_type"]):
            mav_type = PX4_VEHICLE_TYPES.get(int(st["vehicle_type"][0]))
        last_armed: bool | None = None
        last_nav: int | None = None
        for i, t in enumerate(ts):
            if armed_col:
                armed = int(armed_col[i]) == PX4_ARMING_STATE_ARMED
                if armed != last_armed:
                    b.add("armed", t, armed, 0)
                    last_armed = armed
            if nav and int(nav[i]) != last_nav:
                last_nav = int(nav[i])
                b.add("modename", t, PX4_NAV_STATES.get(last_nav, f"nav state {last_nav}"), 0)
                b.add("mode", t, last_nav == PX4_NAV_STATE_OFFBOARD, 0)
        b.count_times("vehicle_status", ts)
    if mav_type is None:
        mav_type = _ulog_vehicle_type(ulog, st, b)
    ld = _topic(ulog, "vehicle_land_detected")
    if ld is not None and "landed" in ld:
        last: int | None = None
        for t, landed in zip(_seconds(ld), ld["landed"].tolist()):
            state = 1 if landed else 2
            if state != last:
                b.add("landed", t, state, 0)
                last = state
        b.count("vehicle_land_detected", len(ld["timestamp"]))
    return b.scan(MAV_AUTOPILOT_PX4, mav_type)


def _ulog_vehicle_type(ulog: Any, status: dict[str, Any] | None, b: _Builder) -> int:
    """The vehicle type of a ULog whose vehicle_status has no ``vehicle_type`` (PX4 before 1.10): its ``MAV_TYPE``
    parameter, else vehicle_status's ``is_rotary_wing``, else a multirotor; a note says which (never silently)."""
    param = ulog.initial_parameters.get("MAV_TYPE") if hasattr(ulog, "initial_parameters") else None
    if param is not None:
        b.notes.append(
            f"the ULog's vehicle_status has no vehicle_type: the vehicle type is its MAV_TYPE parameter ({int(param)})"
        )
        return int(param)
    if status is not None and "is_rotary_wing" in status and len(status["is_rotary_wing"]):
        rotary = bool(status["is_rotary_wing"][0])
        b.notes.append(
            "the ULog states no vehicle type (no vehicle_status.vehicle_type, no MAV_TYPE parameter): vehicle_status."
            f"is_rotary_wing is {int(rotary)}, taken as {'a multirotor' if rotary else 'a fixed wing'}"
        )
        return 2 if rotary else 1
    b.notes.append(
        "the ULog states no vehicle type (no vehicle_status.vehicle_type, MAV_TYPE parameter or is_rotary_wing): "
        "assumed a multirotor, unverified"
    )
    return 2


def _scan_ulog_load_angles(ulog: Any, b: _Builder) -> None:
    """The cable-angle sensor's samples of a ULog: ``debug_vect`` rows named ``LOADANG`` (every instance: PX4 gives
    each DEBUG_VECT sender its own) -> LoadAngle, by the same conversion and plausibility check as the live link's."""
    ts: list[float] = []
    for d in ulog.data_list:
        if d.name != "debug_vect" or "name[0]" not in d.data:
            continue
        chars = [d.data[f"name[{i}]"].tolist() for i in range(10) if f"name[{i}]" in d.data]
        xs, ys, times = d.data["x"].tolist(), d.data["y"].tolist(), _seconds(d.data)
        for i, t in enumerate(times):
            name = bytes(c[i] & 0xFF for c in chars).split(b"\0", 1)[0].decode("ascii", "replace")
            if name != LOAD_ANGLE_NAME or not plausible_load_angles(xs[i], ys[i]):
                continue
            b.add("m", t, load_angle_from_ned(t, xs[i], ys[i]))
            ts.append(t)
    if ts:
        ts.sort()
        b.count_times("debug_vect", ts)


# ---------------------------------------------------------------------------------------------------------------
# ArduPilot DataFlash


def _df_time(m: Any) -> float | None:
    """A DataFlash message's own time (s since boot) from ``TimeUS`` or ``TimeMS``, else None."""
    us = getattr(m, "TimeUS", None)
    if us is not None:
        return us * 1e-6
    ms = getattr(m, "TimeMS", None)
    return None if ms is None else ms * 1e-3


def scan_dataflash(path: Path) -> Scan:
    """An ArduPilot DataFlash log as a :class:`Scan` (see module docstring). UserError when DFReader cannot read
    it."""
    try:
        from pymavlink import DFReader

        reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    except Exception as exc:  # DFReader raises plain Exceptions on a file that is not DataFlash
        raise UserError(f"{path}: not a readable DataFlash log ({type(exc).__name__}: {exc})") from None
    b = _Builder("dataflash")
    pos_msgs: dict[str, list[tuple[float, Any]]] = {"XKF1": [], "NKF1": [], "EKF1": []}
    counts: dict[str, list[float]] = {}
    gyro = (0.0, 0.0, 0.0)
    rate_frd: tuple[float, float, float] | None = None  # RATE's achieved body rates (FRD, as logged) and their time
    t_rate = -math.inf
    n_att = 0
    att_from_rate: list[tuple[float, float, float, float, tuple[float, float, float]]] = []
    rate_abs = gyro_abs = 0.0  # sums of |RATE| and of |IMU gyro| (deg/s) at the RATE records: RATE's unit
    t_now = 0.0
    firmware: str | None = None
    mode_events: list[tuple[float, int, str]] = []
    while True:
        try:
            m = reader.recv_match(type=DF_TYPES)  # DFReader skips the others unparsed (5-10x faster)
        except Exception:  # a damaged tail: keep what was read
            b.notes.append("the DataFlash log is damaged at its end: read up to there")
            break
        if m is None:
            break
        kind = m.get_type()
        t = _df_time(m)
        if kind.startswith(("GPS", "UBX", "GPA")):
            t = None  # old logs stamp GPS messages with the GPS time of week, not the time since boot
        c = counts.setdefault(kind, [0, math.inf, -math.inf])
        c[0] += 1
        if t is not None and t > 0.0:
            c[1] = min(c[1], t)
            c[2] = max(c[2], t)
            if kind in _DF_CLOCK_SOURCES:
                t_now = t
        if kind == "IMU":
            if getattr(m, "I", 0) != 0:
                continue
            gyro = (m.GyrX, m.GyrY, m.GyrZ)
            ax, ay, az = frd_to_model_body(m.AccX, m.AccY, m.AccZ)
            gx, gy, gz = frd_to_model_body(*gyro)
            rec = Imu(t_now, ax, ay, az, gx, gy, gz)
            b.add_measurement(t_now, rec)
        elif kind == "RATE":
            rate_frd = (float(m.R), float(m.P), float(m.Y))  # deg/s, or centideg/s before ArduPilot 3.4: see below
            t_rate = t_now
            rate_abs += abs(rate_frd[0]) + abs(rate_frd[1]) + abs(rate_frd[2])
            gyro_abs += math.degrees(abs(gyro[0]) + abs(gyro[1]) + abs(gyro[2]))
        elif kind == "ATT":
            phi, theta, psi = ned_euler_to_model(math.radians(m.Roll), math.radians(m.Pitch), math.radians(m.Yaw))
            n_att += 1
            if rate_frd is not None and t_now - t_rate <= DF_RATE_MAX_AGE_S:
                att_from_rate.append((t_now, phi, theta, psi, rate_frd))  # converted once RATE's unit is known
                continue
            p, q, r = frd_to_model_body(*gyro)
            rec2 = Attitude(t_now, phi, theta, psi, p, q, r)
            b.add_measurement(t_now, rec2)
        elif kind in pos_msgs:
            if kind == "XKF1" and getattr(m, "C", 0) != 0:
                continue
            pos_msgs[kind].append((t_now, m))
        elif kind == "EV":
            ev = int(m.Id)
            if ev in (DF_EV_ARMED, DF_EV_DISARMED):
                b.add("armed", t_now, ev == DF_EV_ARMED, 0)
            elif ev in (DF_EV_LAND_COMPLETE, DF_EV_NOT_LANDED):
                b.add("landed", t_now, 1 if ev == DF_EV_LAND_COMPLETE else 2, 0)
        elif kind == "ARM":
            b.add("armed", t_now, bool(m.ArmState), 0)
        elif kind == "MODE":
            mode_events.append((t_now, int(getattr(m, "ModeNum", getattr(m, "Mode", -1))), str(m.Mode)))
        elif kind == "SLUP":
            if int(m.Land) == 0 and m.Tens > 0.0:
                t_slup = t if t is not None else t_now
                b.add("payload", t_slup, (float(m.PN), float(m.PE), float(m.PD)))
        elif kind == "MSG" and firmware is None:
            text = str(m.Message).lower()
            for name in ("copter", "plane", "rover", "sub", "heli"):
                if name in text.split(" ")[0]:
                    firmware = name
                    break
    # RATE's unit: deg/s since ArduPilot 3.4, centideg/s before (ArduCopter 3.3's Log_Write_Rate logged the gyro
    # times 100 * 180 / pi); the log does not say (old logs have no FMTU), the IMU gyro does: the same rates
    rate_scale = math.pi / 180.0
    centideg = gyro_abs > 0.0 and rate_abs > RATE_CENTIDEG_RATIO * gyro_abs
    if centideg:
        rate_scale *= 0.01
    for t, phi, theta, psi, (rr, rp, ry) in att_from_rate:
        p, q, r = frd_to_model_body(rr * rate_scale, rp * rate_scale, ry * rate_scale)
        rec2 = Attitude(t, phi, theta, psi, p, q, r)
        b.add_measurement(t, rec2)
    n_att_from_rate = len(att_from_rate)
    if n_att:
        b.sources["body_rates"] = (
            "RATE" if n_att_from_rate == n_att else "IMU gyro" if not n_att_from_rate else "RATE, else IMU gyro"
        )
    if n_att_from_rate:
        b.sources["rate_unit"] = "centideg/s (ArduPilot before 3.4)" if centideg else "deg/s"
    src = next((k for k in ("XKF1", "NKF1", "EKF1") if pos_msgs[k]), None)
    for t, m in pos_msgs[src] if src else []:
        x, y, z = ned_to_model_vector(m.PN, m.PE, m.PD)
        vx, vy, vz = ned_to_model_vector(m.VN, m.VE, m.VD)
        rec3 = PositionVelocity(t, x, y, z, vx, vy, vz)
        b.add_measurement(t, rec3)
    if src is None:
        b.notes.append("no EKF position (XKF1 / NKF1 / EKF1) in the DataFlash log")
    mav_type = ARDUPILOT_FIRMWARE_TYPES.get(firmware or "")
    if mav_type is None:
        mav_type = 2
        b.notes.append("the DataFlash log does not name its firmware (MSG): taken as ArduCopter")
    from offboard.logs.flight_modes import is_offboard_mode, mode_name

    for t, num, _ in mode_events:
        b.add("modename", t, mode_name(MAV_AUTOPILOT_ARDUPILOT, mav_type, 1, num), 0)
        b.add("mode", t, is_offboard_mode(MAV_AUTOPILOT_ARDUPILOT, num, 1, mav_type), 0)
    for kind, (n, t0, t1) in counts.items():
        b.count(kind, int(n), t0 if t1 > t0 else None, t1 if t1 > t0 else None)
    return b.scan(MAV_AUTOPILOT_ARDUPILOT, mav_type)


def scan_log(path: Path) -> Scan:
    """Any log as a :class:`Scan`, by its format (:func:`log_format_of`): tlog, ULog or DataFlash."""
    fmt = log_format_of(path)
    if fmt == "ulog":
        return scan_ulog(path)
    if fmt == "dataflash":
        return scan_dataflash(path)
    from offboard.logs.log_inventory import scan
    from offboard.logs.tlog import TlogReader

    return scan(TlogReader.from_path(path))


__all__ = ["log_format_of", "scan_dataflash", "scan_log", "scan_ulog"]
