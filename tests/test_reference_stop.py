"""The smooth stop after a reference's end (``offboard.control.reference_stop``): it leaves the reference without a
jump in any derivative the law reads (orders 0..6), comes to rest with every derivative zero, keeps the horizontal
F^(6) within its bound, and leaves a reference that is at rest at its end as it is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from offboard.control.reference_patterns import rest_to_rest
from offboard.control.reference_stop import STOP_MAX_F6, STOP_MAX_S, STOP_MIN_S, StoppingReference, stop_duration
from offboard.control.scenarios import make_scenario


def _gap(a, b) -> float:
    """The largest difference between two FlatSamples, every channel and order, relative to each order's scale."""
    return max(abs(x - y) / max(1.0, abs(x)) for ca, cb in zip(a, b, strict=True) for x, y in zip(ca, cb, strict=True))


@pytest.mark.parametrize("name", ["paper", "circle"])
def test_a_moving_reference_is_brought_to_rest_smoothly(name: str) -> None:
    sc = make_scenario(name)
    end = sc.duration
    ref = StoppingReference(sc.reference, end)
    at_end = sc.reference.sample(end)
    speed = math.hypot(at_end.fx[1], at_end.fy[1])
    assert speed > 0.1  # the case is real: these patterns are still moving when the scenario ends
    assert ref.stop_s >= max(STOP_MIN_S, speed / 0.25)
    # up to the end it is the reference itself; just after, the same derivatives (no input of the law jumps)
    for t in (0.0, 0.5 * end, end):
        assert ref.sample(t) == sc.reference.sample(t)
    assert _gap(ref.sample(end + 1e-7), at_end) < 1e-5
    # at the stop's end: at rest, every derivative zero, and no jump into the rest that follows
    done = ref.sample(end + ref.stop_s + 1.0)
    assert all(v == 0.0 for ch in done for v in ch[1:])
    assert _gap(ref.sample(end + ref.stop_s - 1e-7), done) < 1e-5
    # during the stop: the speed never exceeds 1.2 x the end's, the horizontal F^(6) stays within its bound
    ts = np.linspace(end, end + ref.stop_s, 600)
    samples = [ref.sample(t) for t in ts]
    assert max(math.hypot(s.fx[1], s.fy[1]) for s in samples) <= 1.2 * speed
    assert max(max(abs(s.fx[6]), abs(s.fy[6])) for s in samples) <= STOP_MAX_F6 * 1.01
    # it comes to rest about where a symmetric deceleration from the end's speed would (v0 T / 2)
    dist = math.hypot(done.fx[0] - at_end.fx[0], done.fy[0] - at_end.fy[0])
    assert 0.7 < dist / (0.5 * speed * ref.stop_s) < 1.3
    # the heading and height come to rest too
    assert done.z[1] == 0.0 and done.psi[1] == 0.0


def test_a_reference_at_rest_at_its_end_is_left_as_it_is() -> None:
    r = rest_to_rest((0.0, 0.0, 1.0), (3.0, 0.0, 1.0), 0.0, 2.5)
    end = r.duration
    assert stop_duration(r.sample(end)) == 0.0
    ref = StoppingReference(r, end)
    assert ref.stop_s == 0.0
    for t in (0.0, 1.0, end, end + 0.5, end + 30.0):
        assert ref.sample(t) == r.sample(t)


def test_a_faster_end_gets_a_longer_stop_and_a_non_finite_time_is_refused() -> None:
    paper, circle = make_scenario("paper"), make_scenario("circle")
    slow = StoppingReference(paper.reference, paper.duration)  # 0.17 m/s at its end
    fast = StoppingReference(circle.reference, circle.duration)  # 0.63 m/s
    assert STOP_MIN_S < slow.stop_s < fast.stop_s < 0.5 * STOP_MAX_S
    # an end in the middle of a speed ramp (large derivatives of high order): the stop asks no more F^(6) than
    # the reference had there, and stays finite
    ramp = StoppingReference(circle.reference, 2.0)
    f6_end = max(abs(circle.reference.sample(2.0).fx[6]), abs(circle.reference.sample(2.0).fy[6]))
    assert ramp.stop_s < STOP_MAX_S
    ts = np.linspace(2.0, 2.0 + ramp.stop_s, 600)
    assert max(max(abs(s.fx[6]), abs(s.fy[6])) for s in map(ramp.sample, ts)) <= 1.06 * max(STOP_MAX_F6, f6_end)
    with pytest.raises(ValueError, match="non-finite"):
        fast.sample(math.nan)
    with pytest.raises(ValueError, match="finite time"):
        StoppingReference(circle.reference, math.inf)
