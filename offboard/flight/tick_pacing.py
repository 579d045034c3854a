"""When the real-time loop ticks (issue 39): on the telemetry, at the nominal rate.

The loop ticks as soon as a new ATTITUDE arrives, so that the telemetry-to-setpoint latency is the compute time.
Ticking on every arrival, with a deadline 1.5 periods after the previous setpoint, let a jittered link set the rate:
with 5-25 ms of jitter the ATTITUDE records arrive in bunches, each bunch ticked record by record and each pause
ticked on its deadline too, so the loop ran at about 300 Hz against 250 and counted 21 % of its ticks as missed
deadlines (every deadline tick left 1.5 periods plus its compute time after the previous setpoint).

So each tick has a slot on a nominal grid, one period apart. A tick runs on the first trigger that arrives no earlier
than half a period before its slot (a trigger that arrives earlier is ticked at that moment, its data fused), and
at the latest half a period after its slot (its deadline: no trigger came). Each tick moves the slot on by one
period, so the long-run rate is the nominal one whatever the arrivals; a tick on a trigger also pulls the grid a
tenth of the way towards it (``PHASE_GAIN``), so that on a steady link the slots settle where the telemetry arrives
and no tick waits for its window; after a stall the grid restarts from the tick instead of catching up in a burst.
A tick is a missed deadline only if its setpoint left more than a quarter period after its deadline (the machine
was late, not the link) or its compute time exceeded a period.

Times are local monotonic seconds.
"""

from __future__ import annotations

#: how far a tick on a trigger pulls the grid towards it (of the tick's offset from its slot, at most half a period)
PHASE_GAIN = 0.1


class TickPacer:
    """The slot grid of the real-time loop (module docstring); ``period`` in s."""

    def __init__(self, period: float) -> None:
        self.period = period
        #: the current tick's slot (s); None before the first tick (which runs at once)
        self.slot: float | None = None

    def window(self, now: float) -> tuple[float, float]:
        """(earliest time a trigger may be ticked, the deadline) of the current tick (s)."""
        if self.slot is None:
            self.slot = now
        half = 0.5 * self.period
        return self.slot - half, self.slot + half

    def missed(self, sent: float, compute: float) -> bool:
        """Whether the tick whose setpoint left at ``sent`` (s), after ``compute`` s of work, missed its deadline."""
        assert self.slot is not None
        return sent > self.slot + 0.75 * self.period or compute > self.period

    def ticked(self, sent: float, triggered: bool) -> None:
        """The tick's setpoint left at ``sent`` (s), ``triggered`` by telemetry or on its deadline: on to the next
        slot (pulled towards a trigger's time; restarted from ``sent`` after a stall)."""
        assert self.slot is not None
        half = 0.5 * self.period
        off = sent - self.slot
        # only a trigger ticked inside its window tells the telemetry's phase: one held to the window's early edge
        # (it came in a bunch) or ticked on the deadline does not
        pull = PHASE_GAIN * off if triggered and -0.4 * self.period < off < half else 0.0
        self.slot = max(self.slot + self.period + pull, sent)


__all__ = ["PHASE_GAIN", "TickPacer"]
