"""Reference trajectories: exact derivatives (checked against finite differences), C^7 joins, rest, extents,
holding outside the motion, argument checks and trajectory files."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from estimators.errors import UserError
from offboard.control.jet import FACTORIALS, Jet, PolynomialTaylor, compose_series
from offboard.control.reference import (
    Composite,
    FlatSample,
    Mapped,
    Phase,
    PhaseSine,
    Scalar,
    SmoothStep,
    Sum,
    TrajectoryError,
)
from offboard.control.reference_patterns import circle, figure_eight, hover, rest_to_rest, waypoints
from offboard.control.smooth_step import smooth_step_value
from offboard.control.trajectory_file import load_trajectory_file

# --------------------------------------------------------------------------------------------------------------
# the references under test (one per constructor, plus the scenario-style composition)
# --------------------------------------------------------------------------------------------------------------


def _cases() -> dict[str, Composite]:
    f8 = figure_eight((0.5, -0.2), 1.5, 0.75, 20.0, 2.0, t_start=5.0, ramp_time=5.0)
    return {
        "rest_to_rest": rest_to_rest((0.0, 0.0, 1.0, 0.0), (2.0, -1.0, 2.5, 1.0), t_start=1.0, move_time=4.0),
        "circle": circle((1.0, 2.0), 0.8, 8.0, 1.5, t_start=1.0, ramp_time=3.0, laps=2),
        "figure_eight": figure_eight((0.0, 0.0), 1.5, 0.75, 20.0, 2.0, t_start=2.0, ramp_time=6.0, laps=1),
        "waypoints": waypoints([(0, 0, 1), (1, 0, 1.2), (2, 1, 1.5, 0.5), (2, 2, 1.0, -0.3), (0, 2, 1)], speed=0.6),
        "waypoints_velocity": waypoints(
            [(0, 0, 1), (1, 0, 1.2), (2, 1, 1.5, 0.5), (2, 2, 1.0, -0.3), (0, 2, 1)], speed=0.6, shape="velocity"
        ),
        "scenario": f8.replace(z=SmoothStep(1.0, 2.0, 0.0, 5.0), psi=SmoothStep(0.0, 0.4, 0.0, 3.0)),
        "sum_shift": Composite(
            fx=Sum(SmoothStep(0, 1, 0, 2), SmoothStep(0, -0.5, 1.5, 2)).shifted(0.5),
            fy=Mapped(lambda a, b: a * b.sin(), SmoothStep(0.2, 1.0, 0, 3), Phase(1.0, 0.5, 2.0)),
            z=1.0,
            psi=PhaseSine(Phase(0.5, 0.0, 2.0, 3.0), 0.3, cosine=True),
        ),
    }


CASES = _cases()


def _grid(ref: Composite, n: int = 400) -> np.ndarray:
    end = ref.duration if ref.duration > 0 else 5.0
    return np.linspace(-1.0, end + 1.0, n)


def _channel_max(ch: Scalar, ts: np.ndarray, n: int) -> list[float]:
    """max |d_k| over ts for k = 0..n-1."""
    m = [0.0] * n
    for t in ts:
        for k, v in enumerate(ch.derivatives(float(t), n)):
            m[k] = max(m[k], abs(v))
    return m


# --------------------------------------------------------------------------------------------------------------
# jets
# --------------------------------------------------------------------------------------------------------------


def test_jet_derivatives_of_sin_t_squared_match_closed_form():
    t = 0.7
    d = (Jet.variable(t, 5) * Jet.variable(t, 5)).sin().derivatives()
    u = t * t
    s, c = math.sin(u), math.cos(u)
    exact = (
        s,
        2 * t * c,
        2 * c - 4 * t * t * s,
        -12 * t * s - 8 * t**3 * c,
        -12 * s - 48 * t * t * c + 16 * t**4 * s,
    )
    assert d == pytest.approx(exact, rel=1e-12, abs=1e-12)


def test_jet_product_and_composition_are_exact_on_polynomials():
    t, n = 1.3, 8
    x = Jet.variable(t, n)
    p = (x * x * x) * (x * x * x * x) - 2.0 * x + 1.0  # t^7 - 2 t + 1
    for k, dk in enumerate(p.derivatives()):
        exact = math.perm(7, k) * t ** (7 - k) if k <= 7 else 0.0
        exact += {0: -2 * t + 1, 1: -2.0}.get(k, 0.0)
        assert dk == pytest.approx(exact, rel=1e-13)
    # sin(g) by composition with the sine's own series equals the direct sine of the jet
    g = x * x * 0.5 + 0.3
    g0 = g.value
    outer = tuple(math.sin(g0 + k * math.pi / 2) / FACTORIALS[k] for k in range(n))
    assert compose_series(outer, g.c) == pytest.approx(g.sin().c, rel=1e-12, abs=1e-14)
    s, c = g.sincos()
    one = s * s + c * c
    assert one.c[0] == pytest.approx(1.0) and max(abs(v) for v in one.c[1:]) < 1e-12


def test_smooth_step_polynomial_properties():
    step = SmoothStep(0.0, 1.0, 0.0, 1.0)
    assert smooth_step_value(0.5) == pytest.approx(0.5, abs=1e-15)
    assert smooth_step_value(0.25) + smooth_step_value(0.75) == pytest.approx(1.0, abs=1e-14)
    assert step.derivatives(0.5, 2)[1] == pytest.approx(math.comb(16, 8) * 8 / 2**16 * 2, rel=1e-12)  # 15!/(7!)^2/4^7
    # derivatives 1..7 vanish at both ends of the degree-15 polynomial; the 8th does not (so it is exactly C^7)
    from offboard.control import smooth_step

    poly = PolynomialTaylor(smooth_step.STEP.coefficients)
    for x in (0.0, 1.0):
        d = [c * FACTORIALS[k] for k, c in enumerate(poly.taylor(x, 9))]
        assert d[0] == pytest.approx(x, abs=1e-9)
        assert max(abs(v) for v in d[1:8]) < 1e-6 * abs(d[8])
        assert abs(d[8]) > 1e3


# --------------------------------------------------------------------------------------------------------------
# exact derivatives against finite differences
# --------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(CASES))
def test_derivatives_match_central_differences(name):
    """d_k(t) vs (d_{k-1}(t+h) - d_{k-1}(t-h)) / 2h for k = 1..6 on every channel.

    Tolerance per order: the central difference's truncation error is at most h^2/6 max|d_{k+2}| (d_{k+2} is bounded
    because every trajectory is C^7 with bounded 8th derivative), and rounding adds about eps * max|d_{k-1}| / h
    (we allow 1e-11 relative to cover cancellation in the degree-15 polynomials), all times a safety factor 10.
    The test requires that tolerance to be far below the derivative's own size (so a wrong derivative fails).
    """
    ref = CASES[name]
    h = 1e-3
    ts = _grid(ref)
    for label, ch in zip(FlatSample._fields, ref.channels):
        M = _channel_max(ch, np.linspace(ts[0], ts[-1], 3000), 9)
        for k in range(1, 7):
            tol = 10.0 * (h * h / 6.0 * M[k + 2] + 1e-11 * (M[k - 1] + 1.0) / h) + 1e-12
            if M[k] > 0.0:
                assert tol < 1e-3 * M[k], f"{name}.{label}: order {k} test would be meaningless"
            worst = 0.0
            for t in ts:
                t = float(t)
                fd = (ch.derivatives(t + h, k)[k - 1] - ch.derivatives(t - h, k)[k - 1]) / (2 * h)
                worst = max(worst, abs(ch.derivatives(t, k + 1)[k] - fd))
            assert worst <= tol, f"{name}.{label}: order {k} error {worst:.3g} > {tol:.3g}"


def test_sample_matches_channel_jets_and_shapes():
    ref = CASES["scenario"]
    for t in (-3.0, 0.0, 1.7, 4.2, 6.0, 13.0, 80.0):
        s = ref.sample(t)
        assert isinstance(s, FlatSample)
        for got, ch in zip(s, ref.channels):
            assert len(got) == 7 and all(isinstance(v, float) and math.isfinite(v) for v in got)
            assert got == pytest.approx(ch.derivatives(t, 7), rel=1e-14, abs=1e-15)


# --------------------------------------------------------------------------------------------------------------
# continuity at every breakpoint, orders 0..7
# --------------------------------------------------------------------------------------------------------------


def _jumps(ch: Scalar, b: float, span: float) -> list[tuple[int, float, float]]:
    """(order, |jump| across b, tolerance) for orders 0..7; tolerance from the 8th-derivative bound near b."""
    delta = 1e-7 * max(1.0, abs(b))
    M = _channel_max(ch, np.linspace(b - span, b + span, 201), 10)
    left = ch.derivatives(b - delta, 9)
    right = ch.derivatives(b + delta, 9)
    out = []
    for j in range(8):
        tol = 4.0 * delta * M[j + 1] + 1e-9 * (M[j] + 1.0)
        out.append((j, abs(right[j] - left[j]), tol))
    return out


@pytest.mark.parametrize("name", sorted(CASES))
def test_c7_continuity_at_breakpoints(name):
    ref = CASES[name]
    bps = ref.breakpoints
    assert bps, "every case has at least one transition"
    for b in bps:
        for label, ch in zip(FlatSample._fields, ref.channels):
            for j, jump, tol in _jumps(ch, b, 0.05):
                assert jump <= tol, f"{name}.{label}: derivative {j} jumps by {jump:.3g} at t = {b} s"


def test_continuity_check_detects_a_c3_step():
    """The checker above is not blind: a quintic smooth step (C^2, 3rd derivative jumps) fails it at order 3."""

    class Quintic(Scalar):
        def jet(self, t, n=7):
            if t <= 0.0:
                return Jet.constant(0.0, n)
            if t >= 1.0:
                return Jet.constant(1.0, n)
            x = Jet.variable(t, n)
            return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))

        @property
        def breakpoints(self):
            return (0.0, 1.0)

    bad = [j for j, jump, tol in _jumps(Quintic(), 0.0, 0.05) if jump > tol]
    assert bad and min(bad) == 3


def test_phase_rate_is_eighth_order_flat_at_ramp_start():
    """The circle/figure-eight phase is the integral of the C^7 step: derivatives 1..8 vanish at the start."""
    ph = Phase(2.0, 1.0, 3.0)
    eps = 1e-2
    d = ph.derivatives(1.0 + eps, 10)
    # near the start the phase behaves like c eps^9: derivative k ~ eps^(9-k)
    for k in range(1, 9):
        assert abs(d[k]) < 50.0 * eps ** (9 - k) * abs(d[9]), k


# --------------------------------------------------------------------------------------------------------------
# rest, holding, extents
# --------------------------------------------------------------------------------------------------------------


def _at_rest(s: FlatSample) -> bool:
    return all(v == 0.0 for ch in s for v in ch[1:])


def test_rest_to_rest_starts_and_ends_at_rest_and_holds():
    a, b = (0.0, 0.0, 1.0, 0.0), (2.0, -1.0, 2.5, 1.0)
    ref = rest_to_rest(a, b, t_start=1.0, move_time=4.0)
    assert ref.duration == pytest.approx(5.0)
    for t in (-1e6, 0.0, 1.0):
        s = ref.sample(t)
        assert _at_rest(s) and (s.fx[0], s.fy[0], s.z[0], s.psi[0]) == a
    for t in (5.0, 6.0, 1e7):
        s = ref.sample(t)
        assert _at_rest(s) and (s.fx[0], s.fy[0], s.z[0], s.psi[0]) == pytest.approx(b, abs=1e-12)
    mid = ref.sample(3.0)
    assert mid.fx[0] == pytest.approx(1.0, abs=1e-12) and mid.fx[1] > 0.0


def test_waypoints_pass_through_points_start_and_end_at_rest():
    pts = [(0, 0, 1), (1, 0, 1.2), (2, 1, 1.5, 0.5), (2, 2, 1.0, -0.3), (0, 2, 1)]
    ref = waypoints(pts, speed=0.6, t_start=2.0)
    knots = ref.fx.breakpoints
    assert len(knots) == len(pts) and knots[0] == 2.0 and ref.duration == pytest.approx(knots[-1])
    for t, p in zip(knots, pts):
        s = ref.sample(t)
        full = (*p, 0.0) if len(p) == 3 else p
        assert (s.fx[0], s.fy[0], s.z[0], s.psi[0]) == pytest.approx(full, abs=1e-12)
    assert _at_rest(ref.sample(knots[0])) and _at_rest(ref.sample(knots[-1])) and _at_rest(ref.sample(1e5))
    assert _at_rest(ref.sample(-50.0)) and ref.sample(-50.0).fx[0] == 0.0
    # segment times follow the chords at 0.6 m/s (no segment is shorter than the 1 s minimum here)
    for (a, b), (ta, tb) in zip(itertools.pairwise(pts), itertools.pairwise(knots)):
        assert tb - ta == pytest.approx(max(math.dist(a[:3], b[:3]) / 0.6, 1.0))


def test_the_velocity_shape_halves_the_peak_speed_and_is_smooth_at_its_midpoint():
    """``shape = "velocity"``: a segment from rest to rest accelerates over its first half and brakes over its second
    with the smooth step on the velocity: peak speed twice the mean (the position step: 3.14 times), peak
    acceleration 0.83 times the position step's, at the end point at rest, and C^7 at the segment's midpoint too,
    where its two polynomials meet. A segment with a moving end keeps the Hermite piece."""
    D, T, t0 = 2.0, 4.0, 1.0
    pos = waypoints([(0, 0, 2), (D, 0, 2)], segment_times=[T], t_start=t0)
    vel = waypoints([(0, 0, 2), (D, 0, 2)], segment_times=[T], t_start=t0, shape="velocity")
    ts = np.linspace(t0, t0 + T, 4001)
    vp = [pos.channels[0].derivatives(float(t), 3) for t in ts]
    vv = [vel.channels[0].derivatives(float(t), 3) for t in ts]
    assert max(d[1] for d in vv) == pytest.approx(2.0 * D / T, rel=1e-6)
    assert max(d[1] for d in vp) == pytest.approx(3.142 * D / T, rel=1e-3)
    assert max(abs(d[2]) for d in vv) / max(abs(d[2]) for d in vp) == pytest.approx(0.8326, abs=1e-3)
    end = vel.channels[0].derivatives(t0 + T, 8)
    assert end[0] == pytest.approx(D, abs=1e-12) and max(abs(v) for v in end[1:]) < 1e-9
    for j, jump, tol in _jumps(vel.channels[0], t0 + 0.5 * T, 0.05):
        assert jump <= tol, f"derivative {j} jumps by {jump:.3g} at the midpoint"
    # an interior waypoint with a non-zero slope: the same Hermite piece whatever the shape
    a = waypoints([(0, 0, 1), (1, 0, 1), (2, 0, 1)], speed=0.5, shape="velocity").channels[0]
    b = waypoints([(0, 0, 1), (1, 0, 1), (2, 0, 1)], speed=0.5).channels[0]
    assert a.derivatives(1.3, 7) == b.derivatives(1.3, 7)


def test_waypoints_do_not_stop_on_a_straight_line():
    """Equally spaced collinear points: the path keeps moving through interior points, exactly at the chord speed
    on the interior segment (the degree-15 Hermite piece reproduces a straight line)."""
    ref = waypoints([(0, 0, 1), (1, 0, 1), (2, 0, 1), (3, 0, 1)], speed=0.5)
    k = ref.fx.breakpoints
    for t in np.linspace(k[1], k[2], 50):
        s = ref.sample(float(t))
        assert s.fx[1] == pytest.approx(0.5, rel=1e-9) and abs(s.fx[2]) < 1e-9
    assert ref.sample(k[1]).fx[1] == pytest.approx(0.5) and ref.sample(k[2]).fx[1] == pytest.approx(0.5)


def test_waypoints_monotone_data_gives_monotone_path():
    rng = np.random.default_rng(7)
    for _ in range(20):
        xs = np.cumsum(rng.uniform(0.05, 2.0, 6))
        ts = np.cumsum(rng.uniform(0.5, 3.0, 5))
        ref = waypoints([(float(x), 0.0, 1.0) for x in xs], segment_times=[float(t) for t in np.diff(np.r_[0, ts])])
        v = [ref.sample(float(t)).fx[1] for t in np.linspace(0.0, ref.duration, 800)]
        assert min(v) >= -1e-9, "monotone waypoints must not make the path go backwards"


def test_circle_radius_speed_period_and_laps():
    R, P = 0.8, 8.0
    ref = circle((1.0, 2.0), R, P, 1.5, t_start=1.0, ramp_time=3.0, laps=2)
    assert ref.duration == pytest.approx(1.0 + 2 * 3.0 + (2 * P - 3.0))
    for t in np.linspace(-2.0, ref.duration + 2.0, 500):
        s = ref.sample(float(t))
        assert math.hypot(s.fx[0] - 1.0, s.fy[0] - 2.0) == pytest.approx(R, rel=1e-12)
        assert s.z == (1.5, 0, 0, 0, 0, 0, 0)
    cruise = ref.sample(6.0)
    assert math.hypot(cruise.fx[1], cruise.fy[1]) == pytest.approx(2 * math.pi * R / P, rel=1e-12)
    a, b = ref.sample(5.0), ref.sample(5.0 + P)
    assert a.fx == pytest.approx(b.fx, abs=1e-9) and a.fy == pytest.approx(b.fy, abs=1e-9)
    # whole laps: it stops where it started, at rest
    for t in (1.0, ref.duration, ref.duration + 100.0):
        s = ref.sample(t)
        assert (s.fx[0], s.fy[0]) == pytest.approx((1.0 + R, 2.0), abs=1e-9)
    assert _at_rest(ref.sample(ref.duration + 1.0)) and _at_rest(ref.sample(0.0))


def test_figure_eight_extent_and_period():
    sx, sy, P = 1.5, 0.75, 20.0
    ref = figure_eight((0.3, -0.4), sx, sy, P, 2.0, t_start=5.0, ramp_time=5.0)
    t0 = 12.0  # cruising
    ts = np.linspace(t0, t0 + P, 4001)
    xs = np.array([ref.sample(float(t)).fx[0] for t in ts])
    ys = np.array([ref.sample(float(t)).fy[0] for t in ts])
    assert xs.max() - xs.min() == pytest.approx(sx, rel=1e-5)
    assert ys.max() - ys.min() == pytest.approx(sy, rel=1e-5)
    assert (xs.max() + xs.min()) / 2 == pytest.approx(0.3, abs=1e-5)
    assert (ys.max() + ys.min()) / 2 == pytest.approx(-0.4, abs=1e-5)
    a, b, half = ref.sample(t0), ref.sample(t0 + P), ref.sample(t0 + P / 2)
    assert a.fx == pytest.approx(b.fx, abs=1e-9) and a.fy == pytest.approx(b.fy, abs=1e-9)
    assert abs(half.fx[0] - a.fx[0]) > 0.1  # P is the fundamental period in x, not P/2
    # rest before the start, at the center; endless: duration = end of ramp + two periods, and far times are finite
    s = ref.sample(4.0)
    assert _at_rest(s) and (s.fx[0], s.fy[0]) == (0.3, -0.4)
    assert ref.duration == pytest.approx(5.0 + 5.0 + 2 * P)
    assert all(math.isfinite(v) for ch in ref.sample(1e7) for v in ch)


def test_hover_holds_everything():
    ref = hover(1.0, -2.0, 3.0, 0.5)
    assert ref.duration == 0.0
    for t in (-1e9, 0.0, 1e9):
        s = ref.sample(t)
        assert (s.fx[0], s.fy[0], s.z[0], s.psi[0]) == (1.0, -2.0, 3.0, 0.5) and _at_rest(s)


def test_scenario_composition_channels_and_duration():
    ref = CASES["scenario"]
    assert ref.sample(0.0).z[0] == 1.0 and ref.sample(5.0).z[0] == pytest.approx(2.0)
    assert ref.sample(3.0).psi[0] == pytest.approx(0.4) and ref.sample(1.5).psi[1] > 0
    assert _at_rest(ref.sample(5.0)._replace(z=(0.0,) * 7, psi=(0.0,) * 7))
    assert ref.sample(6.0).fx[1] > 0.0
    assert Composite(fx=1.0).duration == 0.0 and Composite(z=SmoothStep(0, 1, 2, 3)).duration == 5.0
    assert ref.replace(duration=42.0).duration == 42.0


# --------------------------------------------------------------------------------------------------------------
# bad arguments
# --------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (lambda: rest_to_rest((0, 0, 1), (1, 0, 1), 0.0, -1.0), "move_time"),
        (lambda: rest_to_rest((0, 0, 1), (1, 0, 1), 0.0, 0.0), "move_time"),
        (lambda: rest_to_rest((0, 0, float("nan")), (1, 0, 1), 0.0, 1.0), "finite"),
        (lambda: rest_to_rest((0, 0), (1, 0, 1), 0.0, 1.0), "start"),
        (lambda: SmoothStep(0, 1, 0, -2.0), "duration"),
        (lambda: circle((0, 0), -1.0, 5.0, 1.0), "radius"),
        (lambda: circle((0, 0), 1.0, float("inf"), 1.0), "period"),
        (lambda: circle((0, 0, 0), 1.0, 5.0, 1.0), "center"),
        (lambda: figure_eight((0, 0), 1.0, 0.5, 10.0, 1.0, ramp_time=-1.0), "ramp_time"),
        (lambda: figure_eight((0, 0), 1.0, 0.5, 10.0, 1.0, ramp_time=15.0, laps=1), "longer"),
        (lambda: figure_eight((0, 0), 1.0, 0.5, 10.0, 1.0, laps=0), "laps"),
        (lambda: waypoints([], speed=1.0), "empty"),
        (lambda: waypoints([(0, 0, 1), (1, 0, 1)]), "speed"),
        (lambda: waypoints([(0, 0, 1), (1, 0, 1)], speed=-1.0), "speed"),
        (lambda: waypoints([(0, 0, 1), (1, 0, 1)], segment_times=[1.0, 2.0]), "segment"),
        (lambda: waypoints([(0, 0, 1), (1, 0, 1)], segment_times=[float("nan")]), "finite"),
        (lambda: hover(0.0, 0.0, float("nan")), "finite"),
    ],
)
def test_bad_arguments_raise_clear_errors(build, match):
    with pytest.raises(TrajectoryError, match=match) as info:
        build()
    assert isinstance(info.value, UserError) and isinstance(info.value, ValueError)
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------------------------------------------
# trajectory files
# --------------------------------------------------------------------------------------------------------------


def _same(a: Composite, b: Composite, ts) -> None:
    assert a.duration == pytest.approx(b.duration)
    for t in ts:
        flat_a = [v for ch in a.sample(float(t)) for v in ch]
        flat_b = [v for ch in b.sample(float(t)) for v in ch]
        assert flat_a == pytest.approx(flat_b, rel=1e-12, abs=1e-12)


def test_trajectory_file_waypoints_with_speed(tmp_path):
    f = tmp_path / "w.toml"
    f.write_text(
        'kind = "waypoints"\nspeed = 0.6\nt_start = 2.0\n'
        "[[waypoint]]\nx = 0.0\ny = 0.0\nz = 1.0\n"
        "[[waypoint]]\nx = 1.0\ny = 0.5\nz = 1.5\npsi_deg = 90\n"
        "[[waypoint]]\nx = 2.0\ny = 0.0\nz = 1.0\npsi = 0.25\n"
    )
    ref = load_trajectory_file(f)
    direct = waypoints([(0, 0, 1, 0), (1, 0.5, 1.5, math.pi / 2), (2, 0, 1, 0.25)], speed=0.6, t_start=2.0)
    _same(ref, direct, np.linspace(0, direct.duration + 1, 60))


def test_trajectory_file_waypoints_with_times_round_trip(tmp_path):
    pts = [(0.0, 0.0, 1.0, 0.0), (1.0, 1.0, 1.2, 0.3), (0.0, 2.0, 1.0, 0.0)]
    times = [1.0, 4.0, 9.0]
    text = "".join(
        f"[[waypoint]]\nt = {t!r}\nx = {p[0]!r}\ny = {p[1]!r}\nz = {p[2]!r}\npsi = {p[3]!r}\n"
        for p, t in zip(pts, times)
    )
    f = tmp_path / "t.toml"
    f.write_text(text)
    ref = load_trajectory_file(f)
    assert ref.duration == 9.0
    for p, t in zip(pts, times):
        s = ref.sample(t)
        assert (s.fx[0], s.fy[0], s.z[0], s.psi[0]) == pytest.approx(p, abs=1e-12)
    _same(ref, waypoints(pts, segment_times=[3.0, 5.0], t_start=1.0), np.linspace(0, 10, 50))


def test_trajectory_file_patterns(tmp_path):
    f = tmp_path / "f8.toml"
    f.write_text(
        'kind = "figure_eight"\ncenter = [0.0, 1.0]\nsize_x = 1.5\nsize_y = 0.75\nperiod = 20.0\nz = 2.0\n'
        "t_start = 5.0\nramp_time = 5.0\nlaps = 2\n"
    )
    _same(
        load_trajectory_file(f),
        figure_eight((0.0, 1.0), 1.5, 0.75, 20.0, 2.0, t_start=5.0, ramp_time=5.0, laps=2),
        np.linspace(0, 60, 80),
    )
    c = tmp_path / "c.toml"
    c.write_text('kind = "circle"\ncenter = [1, 2]\nradius = 0.5\nperiod = 6\nz = 1\npsi_deg = 45\n')
    _same(load_trajectory_file(c), circle((1, 2), 0.5, 6.0, 1.0, psi=math.pi / 4), np.linspace(0, 30, 40))
    h = tmp_path / "h.toml"
    h.write_text('kind = "hover"\nx = 1\ny = 2\nz = 3\n')
    _same(load_trajectory_file(h), hover(1, 2, 3), [0.0, 10.0])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("speed = [", "not valid TOML"),
        ('kind = "spiral"\n', "kind must be one of"),
        ("speed = 1.0\n", "no \\[\\[waypoint\\]\\]"),
        ("speed = 1.0\nsped = 2\n[[waypoint]]\nx=0\ny=0\nz=1\n", "unknown key.*sped"),
        ("speed = 1.0\n[[waypoint]]\nx=0\ny=0\n", "waypoint 1: missing 'z'"),
        ("speed = nan\n[[waypoint]]\nx=0\ny=0\nz=1\n[[waypoint]]\nx=1\ny=0\nz=1\n", "speed must be finite"),
        ("speed = -1.0\n[[waypoint]]\nx=0\ny=0\nz=1\n[[waypoint]]\nx=1\ny=0\nz=1\n", "speed must be > 0"),
        ("[[waypoint]]\nx=0\ny=0\nz=1\nt=2\n[[waypoint]]\nx=1\ny=0\nz=1\nt=1\n", "times must increase"),
        ("[[waypoint]]\nx=0\ny=0\nz=1\nt=0\n[[waypoint]]\nx=1\ny=0\nz=1\n", "t on every waypoint"),
        ('[[waypoint]]\nx="a"\ny=0\nz=1\n', "must be a number"),
        ('kind = "circle"\ncenter = [0]\nradius = 1\nperiod = 5\nz = 1\n', "center"),
        ('kind = "circle"\ncenter = [0, 0]\nradius = 1\nperiod = -5\nz = 1\n', "period"),
        ('kind = "figure_eight"\ncenter = [0, 0]\nsize_x = 1\nperiod = 5\nz = 1\n', "missing 'size_y'"),
        ('kind = "hover"\nx = 1\ny = 2\nz = 3\npsi = 0\npsi_deg = 0\n', "not both"),
        ('shape = "jerk"\nspeed = 1.0\n[[waypoint]]\nx=0\ny=0\nz=1\n', "shape must be one of position, velocity"),
    ],
)
def test_bad_trajectory_files_raise_one_line_user_errors(tmp_path, text, match):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(UserError, match=match) as info:
        load_trajectory_file(f)
    msg = str(info.value)
    assert "\n" not in msg and str(f) in msg


def test_missing_trajectory_file(tmp_path):
    with pytest.raises(UserError, match="cannot read trajectory file"):
        load_trajectory_file(tmp_path / "nope.toml")


def test_examples_in_docs_load(tmp_path):
    import re
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "references.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", doc, flags=re.S)
    assert len(blocks) >= 4
    for i, text in enumerate(blocks):
        f = tmp_path / f"ex{i}.toml"
        f.write_text(text)
        ref = load_trajectory_file(f)
        assert all(math.isfinite(v) for ch in ref.sample(ref.duration / 2) for v in ch)
    examples = re.findall(r"```python\n(from .*?)```", doc, flags=re.S)  # the runnable ones (not the Protocol)
    assert len(examples) == 2
    scope: dict = {}
    exec(examples[0], scope)
    assert scope["s"].z[0] == 2.0 and scope["s"].fx[1] != 0.0
    scope = {}
    exec(examples[1], scope)  # the feasibility check's example
    assert scope["result"].feasible and scope["result"].warnings  # rest-to-rest: its large swing is warned of


def test_numpy_inputs_and_non_finite_time():
    ref = circle(np.array([1.0, 2.0]), np.float64(0.5), 6, np.int64(1))
    assert ref.sample(0.0).fx[0] == 1.5 and isinstance(ref.sample(3.0).fx[0], float)
    wp = waypoints(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]), speed=np.float64(0.5))
    assert wp.duration == pytest.approx(2.0)
    with pytest.raises(TrajectoryError, match="waypoint 1"):
        waypoints([(0, 0, 1), 5.0], speed=1.0)
    for t in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="non-finite"):
            ref.sample(t)
