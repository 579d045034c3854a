"""A small ArduPilot DataFlash (``.bin``) writer for the tests, and the conversion of a PX4 ULog into one.

Why: the only real DataFlash flight the project knows is a third-party log it may not commit, so CI could not test
``slung replay FILE.bin``. The project's own PX4 SITL ULog (``tests/data/px4-sitl-sih-hover.ulg``) is turned here,
during the test, into the same flight in ArduPilot's message layout; pymavlink's DFReader then reads it like any
ArduPilot log.

The format (as pymavlink's ``DFReader_binary`` reads it): a stream of records, each ``0xA3 0x95 <type id>`` then
the little-endian packed fields of that type. Type 128 is ``FMT`` (``Type B, Length B, Name 4s, Format 16s,
Columns 64s``; ``Length`` includes the 3 header bytes), which defines every other type before its first record.
Format characters: ``b B h H i I q Q f d`` plain, ``n N Z`` strings of 4 / 16 / 64 bytes, ``M`` a mode number
(int8), ``c C`` int16 / uint16 x 100, ``e E`` int32 / uint32 x 100, ``L`` int32 degrees x 1e7.

Messages and units follow ArduPilot's log definitions (``libraries/AP_Logger/LogStructure.h``,
``AP_InertialSensor_Logging.cpp``, ``AP_NavEKF3/LogStructure.h``, checked 2026-12-01): ``IMU`` body-frame (FRD)
gyro rad/s and specific force m/s^2; ``ATT`` float degrees (Roll, Pitch, Yaw 0..360); ``XKF1`` EKF3 core ``C``
with Roll / Pitch in centidegrees, Yaw 0..36000 centidegrees, ``VN VE VD`` m/s, ``PN PE PD`` m NED from the EKF
origin; ``EV`` event ids (10 armed, 11 disarmed, 18 land complete, 28 not landed); ``ARM`` (ArmState);
``MODE`` (Mode, ModeNum, Rsn); ``MSG`` text, whose first word names the firmware; ``RATE``
(``AC_AttitudeControl/LogStructure.h``: desired and achieved body rates ``RDes R PDes P YDes Y`` in deg/s, the
achieved ones the AHRS's bias-corrected gyro); ``SLUP`` (``SITL/SIM_SlungPayload.cpp``: ``Land``, ``Tens`` tension
ratio, ``Len`` line length m, ``PN PE PD`` the payload's offset from the vehicle m NED, its velocity, acceleration
and the force on the vehicle).

:func:`sim_dataflash` writes the flight of the project's own plant model (``sim_bridge.plant.dynamics``: a hover with a
swinging load) as ArduCopter SITL would log it, SLUP included, and returns the swing it simulated: a log whose
payload truth is a known answer.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HEAD = b"\xa3\x95"
FMT_TYPE = 128
#: format character -> (struct code, scale applied before packing)
_CODES: dict[str, tuple[str, float | None]] = {
    "b": ("b", None),
    "B": ("B", None),
    "h": ("h", None),
    "H": ("H", None),
    "i": ("i", None),
    "I": ("I", None),
    "q": ("q", None),
    "Q": ("Q", None),
    "f": ("f", None),
    "d": ("d", None),
    "n": ("4s", None),
    "N": ("16s", None),
    "Z": ("64s", None),
    "M": ("b", None),
    "c": ("h", 100.0),
    "C": ("H", 100.0),
    "e": ("i", 100.0),
    "E": ("I", 100.0),
    "L": ("i", 1.0e7),
}

#: name -> (type id, format, columns): ArduPilot 4.x layouts of the messages slung's replay reads (type ids are the
#: log's own choice, defined by its FMT records; these are arbitrary but distinct)
ARDUPILOT_MESSAGES: dict[str, tuple[int, str, str]] = {
    "MSG": (91, "QZ", "TimeUS,Message"),
    "MODE": (92, "QMBB", "TimeUS,Mode,ModeNum,Rsn"),
    "ARM": (93, "QBIBB", "TimeUS,ArmState,ArmChecks,Forced,Method"),
    "EV": (94, "QB", "TimeUS,Id"),
    "IMU": (95, "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "ATT": (96, "QffffffB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,AEKF"),
    "XKF1": (97, "QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH"),
    "RATE": (98, "Qfffffffffffff", "TimeUS,RDes,R,ROut,PDes,P,POut,YDes,Y,YOut,ADes,A,AOut,AOutSlew"),
    "SLUP": (99, "Qbffffffffffffff", "TimeUS,Land,Tens,Len,PN,PE,PD,VN,VE,VD,AN,AE,AD,VFN,VFE,VFD"),
}
EV_ARMED, EV_DISARMED, EV_LAND_COMPLETE, EV_NOT_LANDED = 10, 11, 18, 28
#: PX4 vehicle_status.nav_state -> the ArduCopter mode number flying the same way (PX4's AUTO_TAKEOFF is
#: ArduCopter's AUTO with a take-off item; OFFBOARD is GUIDED)
PX4_NAV_TO_COPTER_MODE = {0: 0, 1: 2, 2: 16, 3: 3, 4: 5, 5: 6, 10: 1, 14: 4, 15: 0, 17: 3, 18: 9}
COPTER_MODE_NAMES = {0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL"}
COPTER_MODE_NAMES.update({9: "LAND", 16: "POSHOLD"})


@dataclass(frozen=True)
class _Type:
    type_id: int
    struct: struct.Struct
    scales: tuple[float | None, ...]
    codes: tuple[str, ...]
    n_fields: int


class DataFlashWriter:
    """Builds a DataFlash byte stream: :meth:`define` a message type (writes its FMT record), then :meth:`write`
    records of it, values in the log's own units before scaling (degrees for ``c``/``C``, not centidegrees)."""

    def __init__(self) -> None:
        self._out = bytearray()
        self._types: dict[str, _Type] = {}
        # the FMT record describes itself first, as ArduPilot's logs do
        self._define_raw(FMT_TYPE, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")

    def _define_raw(self, type_id: int, name: str, fmt: str, columns: str) -> None:
        if len(name) > 4 or len(fmt) > 16 or len(columns) > 64 or len(columns.split(",")) != len(fmt):
            raise ValueError(f"DataFlash type {name!r}: name <= 4, format <= 16, columns <= 64 and one per field")
        packer = struct.Struct("<" + "".join(_CODES[c][0] for c in fmt))
        self._types[name] = _Type(
            type_id, packer, tuple(_CODES[c][1] for c in fmt), tuple(_CODES[c][0] for c in fmt), len(fmt)
        )
        self.write("FMT", type_id, packer.size + 3, name, fmt, columns)

    def define(self, name: str) -> None:
        """Defines one of :data:`ARDUPILOT_MESSAGES` (its FMT record)."""
        type_id, fmt, columns = ARDUPILOT_MESSAGES[name]
        self._define_raw(type_id, name, fmt, columns)

    def write(self, name: str, *values: Any) -> None:
        """One record; strings as bytes or str, scaled fields in their unscaled unit (rounded to the integer)."""
        t = self._types[name]
        if len(values) != t.n_fields:
            raise ValueError(f"{name}: {t.n_fields} fields, {len(values)} given")
        packed = []
        for v, scale, code in zip(values, t.scales, t.codes):
            if isinstance(v, str):
                v = v.encode()
            if isinstance(v, bytes) and len(v) > struct.calcsize(code):
                raise ValueError(f"{name}: {v!r} is longer than its {struct.calcsize(code)}-byte field")
            if scale is not None:
                v = round(v * scale)
            packed.append(v)
        self._out.extend(HEAD + bytes([t.type_id]) + t.struct.pack(*packed))

    def data(self) -> bytes:
        return bytes(self._out)


def _wrap_360(deg: float) -> float:
    return deg % 360.0


def _euler_deg(qw: float, qx: float, qy: float, qz: float) -> tuple[float, float, float]:
    """Roll, pitch, yaw (deg, NED, yaw 0..360 as ArduPilot logs it) of PX4's body-to-NED quaternion."""
    roll = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (qw * qy - qz * qx))))
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return math.degrees(roll), math.degrees(pitch), _wrap_360(math.degrees(yaw))


def _first(ulog: Any, name: str) -> dict[str, Any]:
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0:
            return d.data
    raise ValueError(f"the ULog has no {name}")


def ulog_to_dataflash(path: Path) -> bytes:
    """The flight of a PX4 ULog as an ArduCopter DataFlash log: ``sensor_combined`` -> IMU, ``vehicle_attitude`` ->
    ATT, ``vehicle_local_position`` -> XKF1 core 0, ``vehicle_status`` -> ARM + EV armed / disarmed and MODE,
    ``vehicle_land_detected`` -> EV land complete / not landed, each at the ULog's own times and rates (the values
    are PX4's, in ArduPilot's units and frames: both are FRD body / NED). A state (armed, mode, landed) is written
    at its first sample and at every change, as a log cut out of a longer one starts."""
    from pyulog import ULog

    ulog = ULog(str(path))
    records: list[tuple[int, int, str, tuple[Any, ...]]] = []  # (time us, order, name, values)
    imu = _first(ulog, "sensor_combined")
    for i, t in enumerate(imu["timestamp"].tolist()):
        g = [float(imu[f"gyro_rad[{k}]"][i]) for k in range(3)]
        a = [float(imu[f"accelerometer_m_s2[{k}]"][i]) for k in range(3)]
        records.append((t, 2, "IMU", (t, 0, *g, *a, 0, 0, 25.0, 1, 1, 0, 0)))
    att = _first(ulog, "vehicle_attitude")
    for i, t in enumerate(att["timestamp"].tolist()):
        r, p, y = _euler_deg(*(float(att[f"q[{k}]"][i]) for k in range(4)))
        records.append((t, 3, "ATT", (t, 0.0, r, 0.0, p, 0.0, y, 3)))
    lp = _first(ulog, "vehicle_local_position")
    for i, t in enumerate(lp["timestamp"].tolist()):
        if "xy_valid" in lp and not lp["xy_valid"][i]:
            continue  # the EKF has no horizontal position: ArduPilot does not log one either
        j = min(max(0, int(att["timestamp"].searchsorted(t)) - 1), len(att["timestamp"]) - 1)
        r, p, y = _euler_deg(*(float(att[f"q[{k}]"][j]) for k in range(4)))
        vel = [float(lp[k][i]) for k in ("vx", "vy", "vz")]
        pos = [float(lp[k][i]) for k in ("x", "y", "z")]
        records.append((t, 4, "XKF1", (t, 0, r, p, y, *vel, vel[2], *pos, 0.0, 0.0, 0.0, 0.0)))
    st = _first(ulog, "vehicle_status")
    last_armed: bool | None = None
    last_mode: int | None = None
    for i, t in enumerate(st["timestamp"].tolist()):
        armed = int(st["arming_state"][i]) == 2
        if armed != last_armed:
            records.append((t, 0, "ARM", (t, int(armed), 0, 0, 0)))
            records.append((t, 0, "EV", (t, EV_ARMED if armed else EV_DISARMED)))
            last_armed = armed
        mode = PX4_NAV_TO_COPTER_MODE.get(int(st["nav_state"][i]), 0)
        if mode != last_mode:
            records.append((t, 1, "MODE", (t, mode, mode, 0)))
            last_mode = mode
    ld = _first(ulog, "vehicle_land_detected")
    last_landed: bool | None = None
    for t, landed in zip(ld["timestamp"].tolist(), ld["landed"].tolist()):
        if bool(landed) != last_landed:
            records.append((t, 0, "EV", (t, EV_LAND_COMPLETE if landed else EV_NOT_LANDED)))
            last_landed = bool(landed)
    records.sort(key=lambda r: (r[0], r[1]))
    w = DataFlashWriter()
    for name in ARDUPILOT_MESSAGES:
        w.define(name)
    t0 = records[0][0] if records else 0
    w.write("MSG", t0, f"ArduCopter (PX4 SITL flight {path.name[:36]})")
    for _, _, name, values in records:
        w.write(name, *values)
    return w.data()


def sim_dataflash(
    seconds: float = 8.0,
    *,
    rate: bool = True,
    slup: bool = True,
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0),
    boot_s: float = 12.0,
    rate_centideg: bool = False,
) -> tuple[bytes, list[tuple[float, float, float]]]:
    """An ArduCopter DataFlash log of the plant model's hover with a swinging load (the paper's vehicle, initial
    swing 0.12 / -0.06 rad, small sinusoidal torques; 1 ms RK4 steps), armed and off the ground throughout, in
    LOITER: IMU at 200 Hz (raw gyro: the true body rates plus ``gyro_bias`` rad/s FRD), ATT and RATE (the true
    rates, deg/s, as the AHRS's bias-corrected gyro; ``rate_centideg``: centideg/s, as ArduCopter before 3.4 logged
    them) at 50 Hz, XKF1 at 25 Hz, SLUP at 5 Hz (as the SITL writes it).
    Returns the log's bytes and the simulated swing: (vehicle time s, alpha_x, alpha_y rad) every millisecond."""
    from estimators.model.cable import cable_from_planar, planar_swing
    from estimators.model.vehicle import Vehicle
    from sim_bridge.plant import dynamics
    from sim_bridge.protocol.telemetry import Home, TelemetrySource

    p = dynamics.plant_params(Vehicle())
    r, rd = cable_from_planar(0.12, -0.06)
    x = dynamics.make_state(position=(0.0, 0.0, 2.0), cable=r, cable_rate=rd)
    src = TelemetrySource(p, Home())
    w = DataFlashWriter()
    for name in ARDUPILOT_MESSAGES:
        if (name != "RATE" or rate) and (name != "SLUP" or slup):
            w.define(name)
    t0_us = round(boot_s * 1e6)
    w.write("MSG", t0_us, "ArduCopter V4.6.0 (slung plant model)")
    w.write("ARM", t0_us, 1, 0, 0, 0)
    w.write("EV", t0_us, EV_ARMED)
    w.write("EV", t0_us, EV_NOT_LANDED)
    w.write("MODE", t0_us, 5, 5, 0)
    truth: list[tuple[float, float, float]] = []
    for k in range(round(seconds * 1000) + 1):
        t = k * 1e-3
        t_us = t0_us + k * 1000
        u = dynamics.hover_input(p)
        u[1] = 0.002 * math.sin(3.0 * t)
        u[2] = 0.002 * math.cos(2.0 * t)
        a_y, a_x, _, _ = planar_swing(x[12], x[13], x[14], 0.0, 0.0, 0.0)
        truth.append((t_us * 1e-6, a_x, a_y))
        s = src.snapshot(t_us, x, u) if k % 5 == 0 else None
        if s is not None:
            gyro = [g + b for g, b in zip(s.gyro, gyro_bias)]
            w.write("IMU", t_us, 0, *gyro, *s.acc, 0, 0, 25.0, 1, 1, 0, 0)
        if s is not None and k % 20 == 0:
            if rate:  # the attitude controller logs RATE before the AHRS's ATT of the same loop
                rr, pp, yy = (math.degrees(v) * (100.0 if rate_centideg else 1.0) for v in (s.p, s.qr, s.r))
                w.write("RATE", t_us, rr, rr, 0.0, pp, pp, 0.0, yy, yy, 0.0, 0.0, 0.0, 0.0, 0.0)
            roll, pitch, yaw = (math.degrees(a) for a in (s.roll, s.pitch, s.yaw))
            w.write("ATT", t_us, roll, roll, pitch, pitch, yaw % 360.0, yaw % 360.0, 3)
        if s is not None and k % 40 == 0:
            yaw_deg = math.degrees(s.yaw) % 360.0
            pos, vel = s.pos, s.vel
            roll, pitch = math.degrees(s.roll), math.degrees(s.pitch)
            w.write("XKF1", t_us, 0, roll, pitch, yaw_deg, *vel, vel[2], *pos, 0.0, 0.0, 0.0, 0.0)
        if slup and s is not None and k % 200 == 0:
            off = [a - b for a, b in zip(s.load_pos, s.pos)]
            w.write("SLUP", t_us, 0, 1.0, math.dist(s.load_pos, s.pos), *off, *s.load_vel, *([0.0] * 6))
        x = dynamics.rk4_step(x, u, p, 1e-3, t)
    return w.data(), truth


__all__ = ["ARDUPILOT_MESSAGES", "COPTER_MODE_NAMES", "DataFlashWriter", "sim_dataflash", "ulog_to_dataflash"]
