"""estimators/model/cable.py: spherical <-> r <-> planar round trips, rates against finite differences, and the
rest position alpha = 0 (where beta is undefined) handled without NaN, and the swing amplitude."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.model.cable import cable_from_planar, cable_from_spherical, planar_swing, swing_amplitude, swing_angles


def _tangent_ok(r: tuple[float, ...], rd: tuple[float, ...]) -> None:
    assert math.sqrt(sum(c * c for c in r)) == pytest.approx(1.0, abs=1e-15)
    assert abs(sum(a * b for a, b in zip(r, rd))) < 1e-13


def test_spherical_round_trip() -> None:
    rng = np.random.default_rng(11)
    for _ in range(300):
        a, b = rng.uniform(0.01, math.pi - 0.01), rng.uniform(-math.pi + 1e-9, math.pi)
        ad, bd = rng.normal(), rng.normal()
        r, rd = cable_from_spherical(a, b, ad, bd)
        _tangent_ok(r, rd)
        s = swing_angles(*r, *rd)
        assert s.alpha == pytest.approx(a, abs=1e-12)
        assert s.beta == pytest.approx(b, abs=1e-12)
        assert s.alpha_rate == pytest.approx(ad, abs=1e-12)
        assert s.beta_rate == pytest.approx(bd, abs=1e-10)
        # and back
        r2, rd2 = cable_from_spherical(s.alpha, s.beta, s.alpha_rate, s.beta_rate)
        np.testing.assert_allclose(r2, r, atol=1e-14)
        np.testing.assert_allclose(rd2, rd, atol=1e-12)


def test_planar_round_trip_and_agreement_with_swing_angles() -> None:
    rng = np.random.default_rng(12)
    for _ in range(300):
        ay, ax = rng.uniform(-1.4, 1.4, size=2)
        ayd, axd = rng.normal(size=2)
        r, rd = cable_from_planar(ay, ax, ayd, axd)
        _tangent_ok(r, rd)
        assert r[2] < 0.0  # load below the vehicle
        got = planar_swing(*r, *rd)
        np.testing.assert_allclose(got, (ay, ax, ayd, axd), atol=1e-12)
        s = swing_angles(*r, *rd)
        np.testing.assert_allclose((s.alpha_y, s.alpha_x, s.alpha_y_rate, s.alpha_x_rate), got, atol=1e-15)
        # C5: alpha_y = atan2(S_a C_b, C_a), alpha_x = atan2(S_a S_b, C_a)
        sa, ca = math.sin(s.alpha), math.cos(s.alpha)
        assert s.alpha_y == pytest.approx(math.atan2(sa * math.cos(s.beta), ca), abs=1e-12)
        assert s.alpha_x == pytest.approx(math.atan2(sa * math.sin(s.beta), ca), abs=1e-12)


def test_planar_sign_conventions() -> None:
    """alpha_y > 0 with the load at +x, alpha_x > 0 with the load at +y (errata C5)."""
    ay, ax, _, _ = planar_swing(0.3, 0.0, -0.95, 0.0, 0.0, 0.0)
    assert ay > 0.0 and ax == 0.0
    ay, ax, _, _ = planar_swing(0.0, 0.3, -0.95, 0.0, 0.0, 0.0)
    assert ax > 0.0 and ay == 0.0
    r, _ = cable_from_spherical(0.4, 0.0)
    assert r[0] > 0.0 and r[2] < 0.0  # beta = 0: swing toward +x, load below


def test_rates_match_finite_differences() -> None:
    """Along a smooth path alpha(t), beta(t): d r/dt, and the planar and spherical angle rates, equal central
    differences of the positions (step 1e-5 s, agreement ~1e-9)."""
    h = 1e-5

    def path(t: float) -> tuple[float, float, float, float]:
        return (
            0.6 + 0.3 * math.sin(1.3 * t),
            0.4 + 2.0 * t + 0.2 * math.cos(t),
            0.39 * math.cos(1.3 * t),
            2.0 - 0.2 * math.sin(t),
        )

    for t in np.linspace(0.0, 3.0, 13):
        a, b, ad, bd = path(t)
        r, rd = cable_from_spherical(a, b, ad, bd)
        rp, _ = cable_from_spherical(*path(t + h)[:2])
        rm, _ = cable_from_spherical(*path(t - h)[:2])
        np.testing.assert_allclose(rd, (np.array(rp) - np.array(rm)) / (2 * h), atol=1e-8)
        s, sp, sm = swing_angles(*r, *rd), swing_angles(*rp, 0, 0, 0), swing_angles(*rm, 0, 0, 0)
        assert s.alpha_rate == pytest.approx((sp.alpha - sm.alpha) / (2 * h), abs=1e-8)
        assert s.beta_rate == pytest.approx((sp.beta - sm.beta) / (2 * h), abs=1e-8)
        assert s.alpha_y_rate == pytest.approx((sp.alpha_y - sm.alpha_y) / (2 * h), abs=1e-8)
        assert s.alpha_x_rate == pytest.approx((sp.alpha_x - sm.alpha_x) / (2 * h), abs=1e-8)


def test_planar_inverse_rates_match_finite_differences() -> None:
    h = 1e-5
    for t in np.linspace(0.0, 2.0, 9):
        ay, ax = 0.5 * math.sin(t), -0.3 + 0.2 * t
        ayd, axd = 0.5 * math.cos(t), 0.2
        _, rd = cable_from_planar(ay, ax, ayd, axd)
        rp, _ = cable_from_planar(0.5 * math.sin(t + h), -0.3 + 0.2 * (t + h))
        rm, _ = cable_from_planar(0.5 * math.sin(t - h), -0.3 + 0.2 * (t - h))
        np.testing.assert_allclose(rd, (np.array(rp) - np.array(rm)) / (2 * h), atol=1e-8)


def test_rest_position_has_no_nan() -> None:
    """alpha = 0: beta is undefined; the module returns beta = 0, beta' = 0 and alpha' = |horizontal r'|."""
    s = swing_angles(0.0, 0.0, -1.0, 0.3, -0.4, 0.0)
    assert all(math.isfinite(v) for v in s)
    assert s.alpha == 0.0 and s.beta == 0.0 and s.beta_rate == 0.0
    assert s.alpha_rate == pytest.approx(0.5)
    assert (s.alpha_y_rate, s.alpha_x_rate) == pytest.approx((0.3, -0.4))  # planar rates stay regular
    s0 = swing_angles(0.0, 0.0, -1.0, 0.0, 0.0, 0.0)
    assert all(v == 0.0 for v in s0)
    assert all(math.isfinite(v) for v in planar_swing(0.0, 0.0, -1.0, 0.1, 0.2, 0.0))
    r, rd = cable_from_spherical(0.0, 1.0, 0.5, 3.0)  # beta' is irrelevant at alpha = 0
    assert r == pytest.approx((0.0, 0.0, -1.0)) and all(math.isfinite(c) for c in rd)
    r, rd = cable_from_planar(0.0, 0.0, 0.1, -0.2)
    assert r == pytest.approx((0.0, 0.0, -1.0)) and rd == pytest.approx((0.1, -0.2, 0.0))
    # load straight above (alpha = pi) is also finite; the planar angles are +-pi there
    s = swing_angles(0.0, 0.0, 1.0, 0.1, 0.0, 0.0)
    assert all(math.isfinite(v) for v in s) and s.alpha == pytest.approx(math.pi)


def test_swing_amplitude_is_constant_along_an_undamped_pendulum() -> None:
    """``swing_amplitude`` of a small-angle pendulum swinging elliptically in both planes, ``a_x = A cos(w t)``,
    ``a_y = B sin(w t)``, is ``sqrt(A^2 + B^2)`` at every phase (it is the loop's settle criterion: a swing that
    only changes phase must not look settled); at rest it is 0."""
    w2 = 9.81 / 0.7
    w = math.sqrt(w2)
    amp_x, amp_y = 0.12, 0.05
    for t in np.linspace(0.0, 3.0, 37):
        a_x, a_y = amp_x * math.cos(w * t), amp_y * math.sin(w * t)
        r_x, r_y = -amp_x * w * math.sin(w * t), amp_y * w * math.cos(w * t)
        assert swing_amplitude(a_x, a_y, r_x, r_y, w2) == pytest.approx(math.hypot(amp_x, amp_y), rel=1e-12)
    assert swing_amplitude(0.0, 0.0, 0.0, 0.0, w2) == 0.0
