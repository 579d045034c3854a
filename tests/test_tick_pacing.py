"""The real-time loop's tick pacing (``offboard/flight/tick_pacing.py``, issue 39) on a simulated clock: ATTITUDE
records sent at 250 Hz reach the loop through a link that delays each by 5-25 ms (order kept, as
``tests/hostile_proxy.py --jitter`` does), so they arrive in bunches. The pacer keeps the nominal rate and counts no
jitter-driven tick as a missed deadline; ticking on every arrival with a deadline 1.5 periods after the previous
setpoint (the loop before) ran fast and counted many, which is what the issue measured (about 300 Hz, 21 %)."""

from __future__ import annotations

import math
import random

import pytest

from offboard.flight.tick_pacing import TickPacer

PERIOD = 0.004
COMPUTE = 0.0003


def arrivals(seconds: float, jitter: tuple[float, float], seed: int = 1) -> list[float]:
    rng = random.Random(seed)
    out, last = [], 0.0
    for k in range(int(seconds / PERIOD)):
        last = max(last, k * PERIOD + rng.uniform(*jitter))
        out.append(last)
    return out


def fly_paced(arr: list[float]) -> tuple[float, float, float]:
    """(rate Hz, missed fraction, median wait from the first pending arrival to its tick, s) of the pacer."""
    pacer, t, i, ticks, missed, waits = TickPacer(PERIOD), arr[0], 0, 0, 0, []
    while i < len(arr):
        early, deadline = pacer.window(t)
        got = arr[i] <= deadline
        tick_at = max(arr[i], early, t) if got else max(deadline, t)
        if got:
            waits.append(tick_at - arr[i])
        while i < len(arr) and arr[i] <= tick_at:
            i += 1
        sent = tick_at + COMPUTE
        missed += pacer.missed(sent, COMPUTE)
        pacer.ticked(sent, got)
        ticks, t = ticks + 1, sent
    span = t - arr[0]
    waits.sort()
    return ticks / span, missed / ticks, waits[len(waits) // 2]


def fly_on_every_arrival(arr: list[float]) -> tuple[float, float]:
    """(rate Hz, missed fraction) of the loop before: a tick per arrival, else 1.5 periods after the last setpoint;
    missed: a setpoint more than 1.5 periods after the previous one."""
    t, i, ticks, missed = arr[0], 0, 0, 0
    last_sent = -math.inf
    while i < len(arr):
        deadline = last_sent + 1.5 * PERIOD
        tick_at = max(arr[i], t) if arr[i] <= deadline or last_sent == -math.inf else deadline
        while i < len(arr) and arr[i] <= tick_at:
            i += 1
        sent = tick_at + COMPUTE
        missed += sent - last_sent > 1.5 * PERIOD and last_sent > -math.inf
        last_sent, ticks, t = sent, ticks + 1, sent
    return ticks / (t - arr[0]), missed / ticks


@pytest.mark.parametrize("jitter", [(0.005, 0.025), (0.0, 0.010), (0.0, 0.050)])
def test_a_jittered_link_keeps_the_nominal_rate_and_misses_nothing(jitter: tuple[float, float]) -> None:
    arr = arrivals(60.0, jitter)
    rate, missed, _ = fly_paced(arr)
    assert abs(rate - 250.0) < 0.5 and missed == 0.0, (rate, missed)
    # the loop before: off the nominal rate (238, 268 and 206 Hz here) and a quarter or more of its ticks "missed"
    old_rate, old_missed = fly_on_every_arrival(arr)
    assert abs(old_rate - 250.0) > 10.0 and old_missed > 0.25, (old_rate, old_missed)


def test_a_steady_link_is_ticked_on_arrival_and_a_silent_one_on_the_deadline() -> None:
    for drift in (1.0, 1.001):  # any phase, and a vehicle clock 0.1 % slow: the grid locks onto the telemetry
        steady = [0.0123 + k * PERIOD * drift for k in range(5000)]
        rate, missed, wait = fly_paced(steady)
        assert abs(rate - 250.0 / drift) < 0.3 and missed == 0.0 and wait < 1e-4, (drift, rate, missed, wait)
    p = TickPacer(PERIOD)
    early, deadline = p.window(10.0)
    assert (early, deadline) == (10.0 - PERIOD / 2, 10.0 + PERIOD / 2)
    # a tick on its deadline is not a miss; one a quarter period later than that is (the machine was late)
    assert not p.missed(deadline + COMPUTE, COMPUTE) and p.missed(deadline + 0.3 * PERIOD, COMPUTE)
    assert p.missed(10.0, 1.1 * PERIOD)  # a compute time over a period is
    p.ticked(deadline + COMPUTE, triggered=False)
    assert p.slot == 10.0 + PERIOD  # the deadline tick does not move the grid
    p.ticked(20.0, triggered=True)  # a stall of 10 s: no burst of catch-up ticks, the grid restarts from the tick
    assert p.window(20.0) == (20.0 - PERIOD / 2, 20.0 + PERIOD / 2)
