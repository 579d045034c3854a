"""Stock ArduPilot flown the way people fly it today: GUIDED with a position target, no swing damping. The baseline
that slung's moves are compared with (``bench/ardupilot_payload_moves.py``), and the way a test lands a vehicle that
``slung fly`` left holding.

Everything goes over SERIAL0 (``tcp:127.0.0.1:5760``) with pymavlink, as a ground station would: GUIDED (mode 4),
arm, MAV_CMD_NAV_TAKEOFF to the height above home, a hold at the take-off point until the load has settled, then one
SET_POSITION_TARGET_LOCAL_NED (position only, local NED) at the goal: ArduPilot's position controller flies it with
its own limits (WPNAV_SPEED, WPNAV_ACCEL, the jerk-limited S-curve). Then LAND (mode 9) and the disarm.

Times are the SITL's boot clock (s, ``time_boot_ms`` of the latest ATTITUDE), the DataFlash's; the move's start is
the ATTITUDE before the target is sent (ATTITUDE streams at 50 Hz here: within 20 ms).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

# MAVLink 2 before pymavlink is first imported: mavutil picks its dialect at import (v1.0 without it, which
# lacks every message above id 255) and that choice holds for the whole process, its other users included
os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
GUIDED, LAND = 4, 9
#: SET_POSITION_TARGET_LOCAL_NED type_mask: position only (velocity, acceleration, yaw and yaw rate ignored)
POSITION_ONLY = 0b110111111000
MAV_FRAME_LOCAL_NED = 1


class StockFlightError(RuntimeError):
    """The stock flight could not be flown (the message says which step failed)."""


@dataclass(frozen=True)
class StockMove:
    """A stock GUIDED move: when it started and when its judged window ended (boot s), and where it went (NED, m)."""

    t_start: float
    t_end: float
    start_ned: tuple[float, float, float]
    goal_ned: tuple[float, float, float]


class GuidedLink:
    """A ground-station link on SERIAL0 that flies GUIDED by position targets (see module docstring)."""

    def __init__(self, url: str, timeout_s: float = 30.0) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=254, source_component=190, retries=3)
        if self.conn.wait_heartbeat(timeout=timeout_s) is None:
            raise StockFlightError(f"no heartbeat on {url} within {timeout_s:g} s")
        self.t_boot = 0.0
        self.ned = (math.nan, math.nan, math.nan)
        self.vel = (math.nan, math.nan, math.nan)
        self.custom_mode = -1
        self.armed = False
        for msg_id, hz in ((30, 50.0), (32, 20.0)):  # ATTITUDE, LOCAL_POSITION_NED
            self._command(MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)

    def _command(self, cmd: int, *params: float) -> None:
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.conn.mav.command_long_send(1, 1, cmd, 0, *p)

    def pump(self, seconds: float) -> None:
        """Read what arrives for ``seconds`` (wall clock), keeping the latest state."""
        t_end = time.monotonic() + seconds
        while True:
            left = t_end - time.monotonic()
            if left <= 0:
                return
            msg = self.conn.recv_match(blocking=True, timeout=min(left, 0.1))
            if msg is None or msg.get_srcSystem() != 1:
                continue
            kind = msg.get_type()
            if kind == "ATTITUDE":
                self.t_boot = msg.time_boot_ms * 1e-3
            elif kind == "LOCAL_POSITION_NED":
                self.ned, self.vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
            elif kind == "HEARTBEAT":
                self.custom_mode = msg.custom_mode
                self.armed = bool(msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    def wait(self, pred: object, timeout_s: float, what: str) -> None:
        """Pump until ``pred()`` holds; StockFlightError naming ``what`` after ``timeout_s``."""
        t_end = time.monotonic() + timeout_s
        while not pred():  # type: ignore[operator]
            if time.monotonic() > t_end:
                raise StockFlightError(f"{what} not reached within {timeout_s:g} s")
            self.pump(0.05)

    def set_mode(self, mode: int) -> None:
        """DO_SET_MODE to an ArduCopter mode number, resent until the heartbeat shows it."""
        for _ in range(10):
            self._command(MAV_CMD_DO_SET_MODE, 1.0, float(mode))
            self.pump(0.5)
            if self.custom_mode == mode:
                return
        raise StockFlightError(f"ArduPilot did not switch to mode {mode}")

    def takeoff(self, height_m: float, timeout_s: float = 40.0) -> None:
        """GUIDED, arm (retried while the pre-arm checks refuse) and climb to ``height_m`` above home."""
        self.set_mode(GUIDED)
        t_end = time.monotonic() + timeout_s
        while not self.armed:
            if time.monotonic() > t_end:
                raise StockFlightError("ArduPilot did not arm")
            self._command(MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            self.pump(1.0)
        self._command(MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, height_m)
        self.wait(lambda: -self.ned[2] >= height_m - 0.1, timeout_s, f"take-off to {height_m:g} m")

    def go_to(self, ned: tuple[float, float, float]) -> None:
        """One position target (local NED, m)."""
        self.conn.mav.set_position_target_local_ned_send(
            0, 1, 1, MAV_FRAME_LOCAL_NED, POSITION_ONLY, *ned, 0, 0, 0, 0, 0, 0, 0, 0
        )

    def land(self, timeout_s: float = 60.0) -> None:
        """LAND and wait for the disarm."""
        self.set_mode(LAND)
        self.wait(lambda: not self.armed, timeout_s, "the disarm after LAND")

    def close(self) -> None:
        """Close the link."""
        self.conn.close()


def fly_stock_move(
    url: str,
    height_m: float,
    distance_m: float,
    heading_ne: tuple[float, float] = (1.0, 0.0),
    settle_s: float = 8.0,
    after_s: float = 16.0,
) -> StockMove:
    """Take off to ``height_m``, hold ``settle_s`` (the load settles from the take-off), fly ``distance_m`` along
    ``heading_ne`` with one position target, hold ``after_s``, land. Returns the move's timing and points."""
    link = GuidedLink(url)
    try:
        link.takeoff(height_m)
        start = (link.ned[0], link.ned[1], -height_m)
        link.go_to(start)
        link.pump(settle_s)
        goal = (start[0] + distance_m * heading_ne[0], start[1] + distance_m * heading_ne[1], start[2])
        link.pump(0.05)
        t_start = link.t_boot
        link.go_to(goal)
        link.pump(after_s)
        t_end = link.t_boot
        link.land()
        return StockMove(t_start, t_end, start, goal)
    finally:
        link.close()


__all__ = ["GuidedLink", "StockFlightError", "StockMove", "fly_stock_move"]
