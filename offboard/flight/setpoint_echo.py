"""Foreign setpoints (issue 39): does the autopilot fly the attitude slung sent?

Another sender on an unsigned link can command the vehicle too: for 1 s, system 42's 100 SET_ATTITUDE_TARGET at
30 deg of roll were obeyed by the emulator (as PX4 would), the load moved and its swing grew by half, and the flight
reported "completed". The autopilot's own ATTITUDE_TARGET stream tells which attitude it is flying: during control
with an attitude output, each ATTITUDE_TARGET is compared with the attitude setpoints slung sent over the last
``window_s`` (the link's delay and ArduPilot's input shaping put the target behind the setpoint), by tilt: the angle
between the two body z axes (yaw is left out: the autopilots handle the heading their own ways). A target farther
than ``event_deg`` from every one of them is a mismatch.

- ``count`` mismatches within ``span_s`` make an episode: an event (``foreign_setpoint``), once per episode (it
  ends after ``span_s`` without a mismatch). A single sample is not enough: a lost or reordered setpoint can leave
  one stale target. Another sender and the loop take turns on the vehicle, so the targets alternate: the mismatches
  recur rather than run on.
- A large mismatch ends the flight (hold: the mode change also ends the other sender's offboard control):
  ``count`` samples above ``abort_deg`` within ``span_s``, or an episode that lasts ``sustained_s``.

Signing the link (``docs/deploy.md``) keeps other senders out in the first place.

Quaternions are on the wire's convention (w, x, y, z, NED -> FRD body) on both sides: no conversion. Times are the
vehicle's (s).
"""

from __future__ import annotations

import math
from collections import deque

#: ATTITUDE_TARGET / SET_ATTITUDE_TARGET type_mask bit: the attitude is ignored
ATTITUDE_IGNORE = 128


def body_z(q: tuple[float, float, float, float] | list[float]) -> tuple[float, float, float]:
    """The body z axis (FRD down) in NED of the attitude quaternion ``q`` (w, x, y, z); unit for a unit ``q``."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z) or 1.0
    w, x, y, z = w / n, x / n, y / n, z / n
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


def tilt_between(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """The angle between two unit axes (rad)."""
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return math.acos(max(-1.0, min(1.0, d)))


class SetpointEcho:
    """The comparison (module docstring). ``sent`` for every attitude setpoint of the control phase, ``target`` for
    every ATTITUDE_TARGET of the autopilot; ``target`` returns what to do: None, ``("event", text)`` or
    ``("abort", text)``."""

    def __init__(
        self,
        event_deg: float = 10.0,
        abort_deg: float = 45.0,
        window_s: float = 0.25,
        count: int = 3,
        span_s: float = 0.5,
        sustained_s: float = 2.0,
    ) -> None:
        self.event_rad, self.abort_rad = math.radians(event_deg), math.radians(abort_deg)
        self.window_s, self.count, self.span_s, self.sustained_s = window_s, count, span_s, sustained_s
        self._sent: deque[tuple[float, tuple[float, float, float]]] = deque()
        self._mismatch: deque[tuple[float, float]] = deque()  # (t, angle) of recent mismatches
        self._episode_start: float | None = None
        self._told = False
        #: the figures for metrics.json
        self.compared = 0
        self.mismatches = 0
        self.episodes = 0
        self.worst_rad = 0.0

    def sent(self, t: float, q: tuple[float, float, float, float] | list[float]) -> None:
        """An attitude setpoint slung sent at vehicle time ``t`` (s)."""
        self._sent.append((t, body_z(q)))
        while self._sent and self._sent[0][0] < t - 4.0 * self.window_s:
            self._sent.popleft()

    def target(self, t: float, q: tuple[float, float, float, float] | list[float]) -> tuple[str, str] | None:
        """The autopilot's ATTITUDE_TARGET at vehicle time ``t`` (s)."""
        near = [z for ts, z in self._sent if t - self.window_s <= ts <= t + 0.02]
        if not near or self._sent[0][0] > t - self.window_s:  # nothing to compare with yet (control just began)
            return None
        self.compared += 1
        zt = body_z(q)
        angle = min(tilt_between(zt, z) for z in near)
        mm = self._mismatch
        while mm and mm[0][0] < t - self.span_s:
            mm.popleft()
        if angle <= self.event_rad:
            if not mm:  # the episode, if any, is over
                self._episode_start, self._told = None, False
            return None
        self.mismatches += 1
        self.worst_rad = max(self.worst_rad, angle)
        mm.append((t, angle))
        if self._episode_start is None:
            self._episode_start = t
        deg = math.degrees(angle)
        if sum(a > self.abort_rad for _, a in mm) >= self.count:
            return "abort", (
                f"the autopilot flies attitude setpoints up to {deg:.0f} deg of tilt from those slung sends "
                f"(limit {math.degrees(self.abort_rad):g} deg): another sender commands the vehicle"
            )
        if t - self._episode_start >= self.sustained_s:
            return "abort", (
                f"the autopilot has flown other attitude setpoints than slung's for {t - self._episode_start:.1f} s "
                f"(now {deg:.0f} deg of tilt apart): another sender commands the vehicle"
            )
        if len(mm) >= self.count and not self._told:
            self._told = True
            self.episodes += 1
            return "event", (
                f"the autopilot flies attitude setpoints {deg:.0f} deg of tilt from those slung sends ({len(mm)} of "
                f"its ATTITUDE_TARGET in {t - mm[0][0]:.2f} s): another sender on the link? (signing keeps them out: "
                "docs/deploy.md)"
            )
        return None

    def summary(self) -> dict[str, float | int]:
        """The ``supervision.attitude_target`` block of metrics.json."""
        return {
            "compared": self.compared,
            "mismatches": self.mismatches,
            "episodes": self.episodes,
            "worst_deg": math.degrees(self.worst_rad),
        }


__all__ = ["ATTITUDE_IGNORE", "SetpointEcho", "body_z", "tilt_between"]
