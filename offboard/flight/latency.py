"""The link's delays, measured during the flight, and the prediction horizon they give the controller.

Two delays matter (both in seconds of vehicle time):

- ``telemetry age`` (vehicle -> us): how old the newest attitude sample is when the tick runs. In lockstep it is
  exact: the tick's time (the step marker) minus the sample's time. In real time it is the sample's arrival,
  mapped to vehicle time through the TIMESYNC clock (``offboard.flight.link.connection.VehicleClock``), minus its sample
  time (an estimate: TIMESYNC assumes a symmetric link);
- ``setpoint way`` (us -> vehicle): how long a setpoint takes to reach the autopilot, from TIMESYNC requests the
  loop sends every ``period_s``. In lockstep the request carries the tick's vehicle time and the autopilot answers
  with its own (``tc1``), so ``tc1 - ts1`` is the one-way delay itself; in real time it is half the round trip.

Each is the median of its last ``window`` samples (robust to jitter and to one late packet). The controller then
acts on the state at the time its setpoint will act: the tick's vehicle time plus the horizon (real time:
``age + way``, the tick's time being the newest sample's time plus the local time since it arrived; lockstep:
``way``, the tick's time being the vehicle's time). The horizon is capped at ``max_horizon_s``, the Kalman filter's
room to predict (its fusion horizon beyond the sensors' own latency, sized at the start of control by
``FlightLoop._size_for_link``).

Watchdog ``latency``: either one-way delay above ``limit_s`` (default 0.1 s, ``--latency-limit``) for ``hold_s``
(1 s) ends the flight in hold: beyond it the prediction carries too much of the vehicle's motion on a model. An
outage is the staleness watchdog's (``--stale-limit``), not this one's: a delay must last to count.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from typing import Any

#: default latency watchdog limit, one-way, s
DEFAULT_LIMIT_S = 0.1
#: accepted range of --latency-limit, s
LIMIT_RANGE_S = (0.01, 0.5)


@dataclass
class LinkLatency:
    """Measured delays and the horizon (module docstring). Times in the loop's clock: vehicle time in lockstep,
    local monotonic time in real time (``now`` arguments)."""

    lockstep: bool
    limit_s: float = DEFAULT_LIMIT_S
    max_horizon_s: float = 0.2
    period_s: float = 0.5
    #: how long (s) a delay must stay above the limit before the watchdog fires: longer than two TIMESYNC periods,
    #: so that in real time the vehicle clock is re-anchored in between (a clock whose rate just changed reads as
    #: telemetry growing old until the next exchange, ``VehicleClock``); a real link's delay stays
    hold_s: float = 1.0
    window: int = 9
    ages: deque[float] = field(default_factory=lambda: deque(maxlen=9))
    ways: deque[float] = field(default_factory=lambda: deque(maxlen=9))
    rtts: deque[float] = field(default_factory=lambda: deque(maxlen=9))
    _pending: dict[int, float] = field(default_factory=dict)
    _last_request: float = -math.inf
    _over_since: float | None = None
    requests: int = 0
    answers: int = 0

    # ----------------------------------------------------------------------------------------- TIMESYNC ---
    def due(self, now: float) -> bool:
        """Whether a TIMESYNC request is due (every ``period_s`` of the loop's clock)."""
        return now - self._last_request >= self.period_s

    def request(self, mav: Any, now: float) -> Any:
        """A TIMESYNC request stamped with ``now`` (s, the loop's clock), to send; remembered for its answer."""
        ns = round(now * 1e9) | 1  # odd: never 0 (0 means "a request" in tc1), and unlike the connection's own
        self._pending[ns] = now
        if len(self._pending) > 32:
            self._pending.pop(next(iter(self._pending)))
        self._last_request = now
        self.requests += 1
        return mav.timesync_encode(0, ns)

    def on_timesync(self, tc1_ns: int, ts1_ns: int, now: float) -> None:
        """An answer: ``tc1`` the autopilot's time (ns), ``ts1`` our request's stamp, received at ``now``."""
        sent = self._pending.pop(ts1_ns, None)
        if sent is None or tc1_ns == 0:
            return
        rtt = now - sent
        if not (0.0 <= rtt < 10.0):
            return
        self.answers += 1
        self.rtts.append(rtt)
        if self.lockstep:  # both stamps are vehicle times: the one-way delay up, exactly
            self.ways.append(min(max(tc1_ns * 1e-9 - sent, 0.0), rtt))
        else:
            self.ways.append(0.5 * rtt)

    # -------------------------------------------------------------------------------------- telemetry ---
    def on_telemetry_age(self, age_s: float) -> None:
        """The age (s) of the newest attitude sample at a tick (see the module docstring for how it is taken)."""
        if math.isfinite(age_s):
            self.ages.append(max(age_s, 0.0))

    # ---------------------------------------------------------------------------------------- figures ---
    @property
    def age_s(self) -> float:
        """Median telemetry age (s), 0 before any sample."""
        return statistics.median(self.ages) if self.ages else 0.0

    @property
    def way_s(self) -> float:
        """Median setpoint way (s), 0 before any answer."""
        return statistics.median(self.ways) if self.ways else 0.0

    def horizon(self) -> float:
        """How far ahead of the tick's time the controller should act (s), within ``0..max_horizon_s``."""
        h = self.way_s if self.lockstep else self.age_s + self.way_s
        return min(max(h, 0.0), self.max_horizon_s)

    def check(self, now: float) -> str | None:
        """A reason if a one-way delay has exceeded the limit for ``hold_s`` of the loop's clock ``now`` (s), the
        ``latency`` watchdog, else None."""
        why = self._over_limit()
        if why is None:
            self._over_since = None
            return None
        if self._over_since is None:
            self._over_since = now
        return why if now - self._over_since >= self.hold_s else None

    def _over_limit(self) -> str | None:
        """A reason if a median delay is above the limit now."""
        if len(self.ages) >= 3 and self.age_s > self.limit_s:
            return f"telemetry {self.age_s * 1e3:.0f} ms old (median), above the limit {self.limit_s * 1e3:.0f} ms"
        if len(self.ways) >= 3 and self.way_s > self.limit_s:
            return (
                f"setpoints take {self.way_s * 1e3:.0f} ms to the vehicle (median), above the limit "
                f"{self.limit_s * 1e3:.0f} ms"
            )
        return None

    def summary(self) -> dict[str, Any]:
        """The ``latency`` block of metrics.json (ms)."""
        return {
            "limit_ms": self.limit_s * 1e3,
            "max_horizon_ms": self.max_horizon_s * 1e3,
            "telemetry_age_ms": self.age_s * 1e3 if self.ages else None,
            "setpoint_way_ms": self.way_s * 1e3 if self.ways else None,
            "round_trip_ms": statistics.median(self.rtts) * 1e3 if self.rtts else None,
            "horizon_ms": self.horizon() * 1e3,
            "timesync_requests": self.requests,
            "timesync_answers": self.answers,
        }


__all__ = ["DEFAULT_LIMIT_S", "LIMIT_RANGE_S", "LinkLatency"]
