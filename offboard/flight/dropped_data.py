"""Data the link refused, told as it happens (issue 39): non-finite telemetry (an autopilot that starts sending NaN),
datagrams of other senders on the link, and frames refused for their signature (another MAVLink system on the
autopilot's own link is told once per system instead: a ground station, a companion, the emulator's load, system 2,
are usual there). Each was refused and counted already (``metrics.json``: ``flight.telemetry.refused_nonfinite``,
``link.foreign*``, ``link.signing``), but only there: a vehicle sending NaN went unreported during the flight.

:class:`DroppedData` compares the counters with what it last reported, once per tick (a few integer reads), and
returns what is new as an event: the first refusal of a kind at once, then at most one event per kind every
``interval_s`` (10 000 NaN records a second must not become 10 000 warning lines), each saying how many since the
last and in all; :meth:`flush` at the end reports what the rate limit held back.
"""

from __future__ import annotations

import math

#: event kind -> what was refused (the event's words)
KINDS = {
    "nonfinite_telemetry": "telemetry records with a non-finite field refused",
    "foreign_sender": "datagrams from other senders than the autopilot dropped",
    "refused_signature": "frames refused for a bad or missing signature",
}

#: the shortest time between two events of one kind (s)
DEFAULT_INTERVAL_S = 5.0


class DroppedData:
    """Refusal counters -> events, rate-limited per kind (module docstring)."""

    def __init__(self, interval_s: float = DEFAULT_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._reported: dict[str, int] = {}
        self._last_t: dict[str, float] = {}

    def check(self, now: float, counts: dict[str, int], force: bool = False) -> list[tuple[str, str]]:
        """``counts``: kind -> the counter now (cumulative); ``now``: the loop's clock (s). The (kind, text) events
        due: a kind whose counter grew, unless its last event is younger than ``interval_s`` (``force``: even so)."""
        due = []
        for kind, n in counts.items():
            before = self._reported.get(kind, 0)
            if n <= before or (not force and now - self._last_t.get(kind, -math.inf) < self.interval_s):
                continue
            self._reported[kind], self._last_t[kind] = n, now
            due.append((kind, f"{n - before} {KINDS.get(kind, kind)} ({n} in all)"))
        return due

    def flush(self, now: float, counts: dict[str, int]) -> list[tuple[str, str]]:
        """At the end of the flight: everything not reported yet, whatever the rate limit."""
        return self.check(now, counts, force=True)


__all__ = ["DEFAULT_INTERVAL_S", "KINDS", "DroppedData"]
