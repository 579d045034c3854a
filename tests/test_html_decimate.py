"""report.html's decimation (``offboard.report.html_report.decimate``): each time bucket's minimum and maximum in
time order, non-finite samples kept where a whole bucket has nothing finite. Checked against the bucket-by-bucket
loop it replaced (written out here), on series with NaN runs, infinities and flat stretches."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from offboard.report.html_report import MAX_POINTS, decimate


def _bucket_loop(t: np.ndarray, y: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    n = len(t)
    if n <= max_points:
        return t, y
    edges = np.linspace(0, n, max(1, max_points // 2) + 1).astype(int)
    keep: list[int] = []
    for a, b in itertools.pairwise(edges):
        if b <= a:
            continue
        seg = y[a:b]
        if not np.any(np.isfinite(seg)):
            keep.append(a)
            continue
        keep.extend(sorted({a + int(np.nanargmin(seg)), a + int(np.nanargmax(seg))}))
    return t[keep], y[keep]


@pytest.mark.parametrize("n", [10, 2001, 4987, 12345, 100_000])
@pytest.mark.parametrize("max_points", [MAX_POINTS, 7, 500])
def test_decimate_keeps_each_buckets_extremes_as_the_loop_did(n: int, max_points: int) -> None:
    rng = np.random.default_rng(n + max_points)
    t = np.arange(n) * 0.004
    y = rng.standard_normal(n)
    y[rng.random(n) < 0.05] = np.nan
    y[rng.random(n) < 0.01] = np.inf
    y[rng.random(n) < 0.01] = -np.inf
    y[min(100, n) : min(400, n)] = np.nan  # whole buckets with nothing finite
    y[min(500, n) : min(520, n)] = 3.0  # ties: the first of them
    td, yd = decimate(t, y, max_points)
    tr, yr = _bucket_loop(t, y, max_points)
    np.testing.assert_array_equal(td, tr)
    np.testing.assert_array_equal(yd, yr)
    assert len(td) <= max(n, 2 * (max_points // 2) + 1) and np.all(np.diff(td) > 0)


def test_decimate_keeps_a_fast_oscillations_envelope() -> None:
    t = np.linspace(0.0, 100.0, 200_001)
    y = np.sin(2 * np.pi * 50.0 * t)  # 50 Hz: many periods per bucket
    td, yd = decimate(t, y)
    assert len(td) <= MAX_POINTS
    assert yd.max() > 0.999 and yd.min() < -0.999
