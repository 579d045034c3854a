"""A passive monitor of ArduPilot SITL on SERIAL1 (tcp 5762): readiness, and the slung payload's own position report.

ArduPilot's payload simulation is MAVLink system 2 (``SIM_SLUP_SYSID``): it sends HEARTBEAT and GLOBAL_POSITION_INT
into SERIAL2, and the autopilot routes them to its other links. The monitor keeps every payload GLOBAL_POSITION_INT
beside the vehicle's own (system 1), so that a flight can be judged by the payload's offset from the vehicle while it
flies: the simulation's truth, as the DataFlash ``SLUP`` is after the flight (``sim_bridge.sitl.ardupilot_dataflash``).
**It is never fed to a filter**: ``slung fly`` talks to SERIAL0 and estimates the swing from the IMU alone; the
monitor is a judge beside it.

What it sends: a GCS HEARTBEAT at 1 Hz (ArduPilot routes system 2's broadcasts only to links it has heard from) and
SET_MESSAGE_INTERVAL for the vehicle's SYS_STATUS, LOCAL_POSITION_NED and GLOBAL_POSITION_INT on this link (ArduPilot's
stream rates are per link: this changes nothing on SERIAL0). No command that flies.

Readiness (:meth:`PayloadMonitor.ready`): SYS_STATUS says the pre-arm checks pass (``MAV_SYS_STATUS_PREARM_CHECK`` in
``onboard_control_sensors_health``) and LOCAL_POSITION_NED arrives (EKF3 uses GPS): about 40 s after boot.

Times are the SITL's boot clock (``time_boot_ms``, s), the DataFlash's ``TimeUS`` clock and ``slung fly``'s
``t_vehicle``. Positions: north / east / down offsets of the payload from the vehicle (m), from the two reports'
latitude, longitude and altitude on a local flat earth.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
import time
from dataclasses import dataclass

# MAVLink 2 before pymavlink is first imported: mavutil picks its dialect at import (v1.0 without it, which
# lacks every message above id 255) and that choice holds for the whole process, its other users included
os.environ.setdefault("MAVLINK20", "1")

import numpy as np
from pymavlink import mavutil

#: the payload's MAVLink system (SIM_SLUP_SYSID's default) and the vehicle's
PAYLOAD_SYSID = 2
VEHICLE_SYSID = 1
#: the monitor's own MAVLink identity (a ground station's system id that nobody else on the link uses)
MONITOR_SYSID = 250
MAV_SYS_STATUS_PREARM_CHECK = 0x10000000
MAV_CMD_SET_MESSAGE_INTERVAL = 511
#: message id -> rate (Hz) asked of the vehicle on the monitor's link
STREAMS = {1: 1.0, 32: 2.0, 33: 10.0}  # SYS_STATUS, LOCAL_POSITION_NED, GLOBAL_POSITION_INT
#: metres per degree of latitude on ArduPilot's spherical earth (LOCATION_SCALING_FACTOR)
M_PER_DEG = 111318.84502145034


@dataclass(frozen=True)
class Fix:
    """One GLOBAL_POSITION_INT: boot time (s), latitude and longitude (deg), altitude AMSL (m), velocity NED (m/s)."""

    t: float
    lat: float
    lon: float
    alt: float
    vn: float
    ve: float
    vd: float


class PayloadMonitor:
    """The SERIAL1 reader thread (see module docstring). Make one with :meth:`attach`; :meth:`close` ends it."""

    def __init__(self, conn: mavutil.mavfile) -> None:
        self._conn = conn
        self._lock = threading.Lock()
        self.payload: list[Fix] = []
        self.vehicle: list[Fix] = []
        self.prearm_ok = False
        self.local_position_seen = False
        self.payload_heartbeats = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ardupilot-payload-monitor", daemon=True)
        self._thread.start()

    @classmethod
    def attach(cls, url: str) -> PayloadMonitor:
        """Connect to ``url`` (``tcp:127.0.0.1:5762``) once; OSError when nothing listens there."""
        try:
            conn = mavutil.mavlink_connection(
                url, source_system=MONITOR_SYSID, source_component=mavutil.mavlink.MAV_COMP_ID_MISSIONPLANNER, retries=0
            )
        except OSError:
            raise
        except Exception as exc:  # pymavlink wraps some socket failures
            raise OSError(str(exc)) from exc
        return cls(conn)

    # ---------------------------------------------------------------------------------------- thread ---
    def _run(self) -> None:
        last_hb = last_req = -math.inf
        mav = self._conn.mav
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now - last_hb >= 1.0:
                    mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                    last_hb = now
                if now - last_req >= 5.0 and not (self.local_position_seen and self.vehicle):
                    for msg_id, hz in STREAMS.items():
                        mav.command_long_send(
                            VEHICLE_SYSID, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / hz, 0, 0, 0, 0, 0
                        )
                    last_req = now
                msg = self._conn.recv_match(blocking=True, timeout=0.2)
            except (OSError, ValueError):  # the SITL went away, or close() closed the socket under us
                return
            if msg is not None:
                self._take(msg)

    def _take(self, msg: object) -> None:
        kind = msg.get_type()  # type: ignore[attr-defined]
        src = msg.get_srcSystem()  # type: ignore[attr-defined]
        if kind == "GLOBAL_POSITION_INT" and src in (PAYLOAD_SYSID, VEHICLE_SYSID):
            fix = Fix(
                msg.time_boot_ms * 1e-3,  # type: ignore[attr-defined]
                msg.lat * 1e-7,  # type: ignore[attr-defined]
                msg.lon * 1e-7,  # type: ignore[attr-defined]
                msg.alt * 1e-3,  # type: ignore[attr-defined]
                msg.vx * 1e-2,  # type: ignore[attr-defined]
                msg.vy * 1e-2,  # type: ignore[attr-defined]
                msg.vz * 1e-2,  # type: ignore[attr-defined]
            )
            with self._lock:
                (self.payload if src == PAYLOAD_SYSID else self.vehicle).append(fix)
        elif src == VEHICLE_SYSID and kind == "SYS_STATUS":
            self.prearm_ok = bool(msg.onboard_control_sensors_health & MAV_SYS_STATUS_PREARM_CHECK)  # type: ignore[attr-defined]
        elif src == VEHICLE_SYSID and kind == "LOCAL_POSITION_NED":
            self.local_position_seen = True
        elif src == PAYLOAD_SYSID and kind == "HEARTBEAT":
            self.payload_heartbeats += 1

    # ----------------------------------------------------------------------------------------- facts ---
    def ready(self) -> bool:
        """Pre-arm checks pass and EKF3 gives a local position (see module docstring)."""
        return self.prearm_ok and self.local_position_seen

    def readiness(self) -> str:
        """What readiness still waits for, in words."""
        return (
            f"pre-arm checks {'pass' if self.prearm_ok else 'not passed'}, "
            f"local position {'streaming' if self.local_position_seen else 'absent'}, "
            f"{len(self.payload)} payload reports"
        )

    def payload_offsets(self, t0: float = -math.inf, t1: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """(t (n,), offsets (n, 3)): the payload's position minus the vehicle's (north, east, down, m) at each payload
        report in ``t0..t1`` (boot s), the vehicle's report interpolated to it; empty without reports of both."""
        with self._lock:
            pay = [f for f in self.payload if t0 <= f.t <= t1]
            veh = list(self.vehicle)
        if not pay or len(veh) < 2:
            return np.zeros(0), np.zeros((0, 3))
        tv = np.array([f.t for f in veh])
        t = np.array([f.t for f in pay])
        keep = (t >= tv[0]) & (t <= tv[-1])
        t = t[keep]
        pay = [f for f, k in zip(pay, keep) if k]
        lat_v = np.interp(t, tv, [f.lat for f in veh])
        lon_v = np.interp(t, tv, [f.lon for f in veh])
        alt_v = np.interp(t, tv, [f.alt for f in veh])
        lat_p = np.array([f.lat for f in pay])
        north = (lat_p - lat_v) * M_PER_DEG
        east = (np.array([f.lon for f in pay]) - lon_v) * M_PER_DEG * np.cos(np.radians(lat_v))
        down = alt_v - np.array([f.alt for f in pay])
        return t, np.column_stack([north, east, down])

    def swing(self, t0: float = -math.inf, t1: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """(t, swing rad): the line's angle from the vertical at each payload report in ``t0..t1``."""
        t, off = self.payload_offsets(t0, t1)
        return t, np.arctan2(np.hypot(off[:, 0], off[:, 1]), off[:, 2]) if len(t) else np.zeros(0)

    def close(self) -> None:
        """End the thread and close the link. Idempotent."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        with contextlib.suppress(Exception):
            self._conn.close()


__all__ = ["M_PER_DEG", "PAYLOAD_SYSID", "Fix", "PayloadMonitor"]
