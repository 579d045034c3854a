"""The staleness watchdog's limit, from the measured link (issue 39).

A fixed 0.1 s limit ended one flight in seven on pauses the vehicle survives: the emulator's own 90-400 ms stalls,
ArduPilot SITL's 100-137 ms ones; real links (radios, USB, busy companion computers) pause too, and PX4's own
offboard-loss timeout is 1 s (``COM_OF_LOSS_T``). So the loop measures each watched telemetry stream's gaps while
the vehicle holds before control (priming and the approach: the link as it is while setpoints stream at the loop's
rate), and from the start of control the limit is ``GAP_FACTOR`` times the longest of those gaps, within a floor and
a ceiling the user sets (``--stale-floor``, ``--stale-ceiling``; ``--stale-limit S`` fixes both). Before the limit is
derived (and for a stream not seen in the hold) the floor applies.

A gap shorter than the limit is flown through on the filter's prediction: the loop ticks on its deadline (real
time) or the predicted step (lockstep) with the commands it sent, as it always did; what is new is that such a gap,
when longer than any the hold showed (and at least ``REPORT_MIN_S``), is reported (an event, and counted in
``metrics.json``'s ``loop.staleness``) once the stream resumes.

Stamps are the loop's staleness clock: local arrival time (s, monotonic) in real time, the sample's vehicle time
(s) in lockstep (where wall time means nothing to the vehicle).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: the streams the staleness watchdog watches (measurement record type names)
WATCHED = ("Attitude", "PositionVelocity")
#: default floor and ceiling of the limit (s): half PX4's own offboard-loss timeout at least (at 0.3 s, 1 of 3 paper
#: flights against the real-time emulator at load 10-12 still ended on a 333 ms stall, bench/nominal_flights.py,
#: 7 Dec 2026; the issue's emulator stalls reached 400 ms)
STALE_FLOOR_S = 0.5
STALE_CEILING_S = 1.0
#: the limit is this many times the longest gap of the hold
GAP_FACTOR = 3.0
#: a bridged gap shorter than this (s) is not reported even if the hold showed none as long
REPORT_MIN_S = 0.05
#: gaps kept per stream for the statistics (a hold of 40 s at 250 Hz)
_KEEP = 10_000


class Staleness:
    """Per-stream gaps and the staleness limit (s). ``measure()`` when the hold starts, ``derive()`` at the start of
    control; ``on_sample`` for every watched record, which returns a bridged gap to report (else None)."""

    def __init__(self, floor_s: float = STALE_FLOOR_S, ceiling_s: float = STALE_CEILING_S) -> None:
        if not (0.0 < floor_s <= ceiling_s):
            raise ValueError(f"staleness floor {floor_s:g} s must be > 0 and not above the ceiling {ceiling_s:g} s")
        self.floor_s, self.ceiling_s = floor_s, ceiling_s
        self.limit_s = floor_s
        self.report_s = math.inf
        self.derived_from = "the floor (no hold measured yet)"
        self.hold_gaps: dict[str, list[float]] = {k: [] for k in WATCHED}
        self.bridged: list[tuple[str, float]] = []
        self._last: dict[str, float] = {}
        self._measuring = False
        self._controlling = False

    def measure(self) -> None:
        """The hold starts: gaps from here on are the link's (earlier stamps may span the loop's own start-up)."""
        self._last.clear()
        self._measuring = True

    def on_sample(self, stream: str, stamp: float) -> float | None:
        """A record of watched ``stream`` at ``stamp`` (s); the gap (s) before it if it is one to report."""
        prev = self._last.get(stream)
        if prev is not None and stamp <= prev:
            return None  # a duplicate or a reordered record: no gap
        self._last[stream] = stamp
        if prev is None:
            return None
        gap = stamp - prev
        if self._measuring:
            gaps = self.hold_gaps[stream]
            if len(gaps) < _KEEP:
                gaps.append(gap)
        elif self._controlling and gap > self.report_s:
            self.bridged.append((stream, gap))
            return gap
        return None

    def derive(self) -> str:
        """At the start of control: fix the limit from the hold's gaps; a one-line account of it."""
        self._measuring, self._controlling = False, True
        longest = max((max(g) for g in self.hold_gaps.values() if g), default=0.0)
        raw = GAP_FACTOR * longest
        self.limit_s = min(max(raw, self.floor_s), self.ceiling_s)
        self.report_s = max(longest, REPORT_MIN_S)
        if longest == 0.0:
            self.derived_from = "the floor (no gaps measured in the hold)"
        elif raw < self.floor_s:
            self.derived_from = f"the floor ({GAP_FACTOR:g} x the hold's longest gap is {raw * 1e3:.0f} ms)"
        elif raw > self.ceiling_s:
            self.derived_from = f"the ceiling ({GAP_FACTOR:g} x the hold's longest gap is {raw * 1e3:.0f} ms)"
        else:
            self.derived_from = f"{GAP_FACTOR:g} x the hold's longest gap ({longest * 1e3:.0f} ms)"
        parts = []
        for k, g in self.hold_gaps.items():
            if g:
                a = np.asarray(g) * 1e3
                parts.append(f"{k} p50 {np.median(a):.1f} / p99 {np.percentile(a, 99):.1f} / max {a.max():.1f} ms")
        gaps = "; ".join(parts) or "none measured"
        return (
            f"telemetry gaps in the hold: {gaps}: staleness limit {self.limit_s * 1e3:.0f} ms, {self.derived_from} "
            f"(floor {self.floor_s:g} s, ceiling {self.ceiling_s:g} s)"
        )

    def stop(self) -> None:
        """Control ended (the hand-over): gaps from here on are not the watchdog's, and not reported."""
        self._measuring = self._controlling = False

    def summary(self) -> dict[str, Any]:
        """The ``loop.staleness`` block of metrics.json (s)."""

        def stats(g: list[float]) -> dict[str, Any]:
            if not g:
                return {"n": 0}
            a = np.asarray(g)
            p50, p99 = float(np.median(a)), float(np.percentile(a, 99))
            return {"n": len(g), "p50_s": p50, "p99_s": p99, "max_s": float(a.max())}

        return {
            "limit_s": self.limit_s,
            "floor_s": self.floor_s,
            "ceiling_s": self.ceiling_s,
            "derived_from": self.derived_from,
            "hold_gaps": {k: stats(g) for k, g in self.hold_gaps.items()},
            "bridged_gaps": len(self.bridged),
            "bridged_gap_max_s": max((g for _, g in self.bridged), default=0.0),
        }


__all__ = ["GAP_FACTOR", "STALE_CEILING_S", "STALE_FLOOR_S", "WATCHED", "Staleness"]
