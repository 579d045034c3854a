"""The vehicle's clock seen from the companion computer: local monotonic time <-> the vehicle's boot time (s), from
TIMESYNC round trips or, without them, from the message stamps (``offboard.flight.link.connection``). Used for
staleness and latency figures; the filters place records by the vehicle's own sample times."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

#: TIMESYNC exchanges the vehicle clock's line is fitted through (one every 0.5 s: the last 4 s)
SYNC_WINDOW = 8
#: how far (s) an exchange may fall from the clock's prediction for the clock to count as steady
STEADY_S = 0.005


@dataclass
class VehicleClock:
    """Vehicle time (s since its boot) <-> local monotonic time (s). See module docstring."""

    drift: float = 1e-4
    offset: float | None = None
    source: str = "none"
    best_rtt: float = float("inf")
    rate: float = 1.0  # vehicle seconds per local second, fitted from TIMESYNC exchanges
    rate_fitted: bool = False  # whether ``rate`` comes from three exchanges over a second or more
    steady: bool = False  # whether the latest exchange agreed with the clock before it (``observe_timesync``)
    _last_local: float | None = None
    _line: tuple[float, float] | None = None  # (local, vehicle) of the latest good exchange: the clock's anchor
    _sync: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=SYNC_WINDOW))

    def observe(self, vehicle_t: float, local_t: float) -> None:
        """A telemetry sample stamped ``vehicle_t`` arrived at ``local_t``."""
        if self.source == "timesync":
            return
        sample = local_t - vehicle_t
        if self.offset is None:
            self.offset, self.source = sample, "telemetry"
        else:
            creep = 0.0 if self._last_local is None else self.drift * max(0.0, local_t - self._last_local)
            self.offset = min(self.offset + creep, sample)
        self._last_local = local_t

    def observe_timesync(self, vehicle_t: float, local_send: float, local_recv: float) -> None:
        """A TIMESYNC round trip: sent at ``local_send``, answered with ``vehicle_t``, back at ``local_recv``.

        The round trip's midpoint is the local time of ``vehicle_t`` (a symmetric link). The clock runs from the
        latest good exchange at the rate fitted through the last ``SYNC_WINDOW`` of them, so that it follows a
        vehicle clock whose rate is not ours: PX4 SITL's runs 3-25 % slow on a loaded machine, which a fixed
        offset (kept from the best round trip) turned into telemetry "ages" of 0.1-1 s and false latency alarms
        within seconds. The line is anchored at the latest exchange, not at the exchanges' centroid: extrapolated
        2 s from the centroid, a rate that changed by 5 % is 0.1 s off (a CI run's false 101 ms alarm), from the
        latest exchange at most 0.5 s. ``steady`` says whether the latest exchange fell where the earlier ones
        predicted (within ``STEADY_S`` plus half its round trip, the most a midpoint can be off): while the
        vehicle clock's rate is changing, its extrapolation says little and the loop takes no telemetry age from
        it. An exchange off the prediction restarts the fit from the previous exchange, so that the new rate is
        followed within two exchanges rather than a window's length.
        """
        rtt = local_recv - local_send
        if rtt < 0.0:
            return
        if rtt <= self.best_rtt or self.source != "timesync":
            self.best_rtt = rtt
        else:
            self.best_rtt += 1e-3  # let old exchanges age, so that a slower link is accepted again
        if rtt > 2.0 * self.best_rtt + 2e-3:  # a slow exchange: its midpoint says little
            return
        mid = 0.5 * (local_send + local_recv)
        # where the clock so far put this exchange (within what the round trip's asymmetry allows): steady if there,
        # else the rate changed, and the exchanges before the previous one describe the old rate: fit anew
        sync = self._sync
        has_rate = len(sync) >= 2 and sync[-1][0] - sync[0][0] >= 0.4
        predicted_ok = has_rate and abs(self.to_vehicle(mid) - vehicle_t) <= STEADY_S + 0.5 * rtt
        if has_rate and not predicted_ok:
            while len(sync) > 1:
                sync.popleft()
        sync.append((mid, vehicle_t))
        n = len(sync)
        lbar = sum(p[0] for p in sync) / n
        vbar = sum(p[1] for p in sync) / n
        sll = sum((p[0] - lbar) ** 2 for p in sync)
        rate = self.rate
        if n >= 2 and sync[-1][0] - sync[0][0] >= 0.4:  # exchanges 0.4 s or more apart: the slope is meaningful
            rate = sum((p[0] - lbar) * (p[1] - vbar) for p in sync) / sll
            if not 0.2 <= rate <= 5.0:  # a clock jump (reboot) rather than a rate: start again from this exchange
                sync.clear()
                sync.append((mid, vehicle_t))
                rate = 1.0
        self.rate = rate
        self.rate_fitted = len(sync) >= 3 and sync[-1][0] - sync[0][0] >= 0.9
        self.steady = self.rate_fitted and predicted_ok
        self._line = (mid, vehicle_t)
        self.offset = mid - vehicle_t
        self.source = "timesync"

    def to_local(self, vehicle_t: float) -> float:
        """Local time of a vehicle time (vehicle time itself before any observation)."""
        if self._line is not None:
            lbar, vbar = self._line
            return lbar + (vehicle_t - vbar) / self.rate
        return vehicle_t + (self.offset or 0.0)

    def to_vehicle(self, local_t: float) -> float:
        """Vehicle time of a local time."""
        if self._line is not None:
            lbar, vbar = self._line
            return vbar + self.rate * (local_t - lbar)
        return local_t - (self.offset or 0.0)


__all__ = ["STEADY_S", "SYNC_WINDOW", "VehicleClock"]
