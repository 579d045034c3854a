"""Random disturbances: bounded, band-limited, seeded, smooth onset; the vectorized grid equals point calls."""

from __future__ import annotations

import numpy as np

from sim_bridge.plant.disturbances import DisturbanceSpec, RandomDisturbance


def test_bounded_zero_before_onset_and_grid_matches_calls() -> None:
    spec = DisturbanceSpec(force_xyz=(0.5, 0.4, 0.3), torque_psi=0.02, start=2.0, ramp=1.0)
    d = RandomDisturbance(spec, seed=11)
    t = np.linspace(0.0, 60.0, 60001)
    grid = d.sample_grid(t)
    calls = np.array([d(float(ti)) for ti in t[::97]])
    assert np.allclose(grid[::97], calls, atol=1e-15)
    assert np.all(grid[t <= 2.0] == 0.0)
    bounds = (0.5, 0.4, 0.3)
    for col, bound in zip((0, 1, 2), bounds):
        assert np.max(np.abs(grid[:, col])) <= bound
        assert np.max(np.abs(grid[:, col])) > 0.3 * bound  # it does disturb
    assert np.max(np.abs(grid[:, 8])) <= 0.02
    assert np.all(grid[:, 3:8] == 0.0)  # no load force, no roll/pitch torque
    # smooth onset: no jump at the start
    assert np.max(np.abs(np.diff(grid[:, 0]))) < 0.01


def test_band_limited_and_seeded() -> None:
    spec = DisturbanceSpec(band=(0.1, 2.0), start=0.0, ramp=0.0)
    a = RandomDisturbance(spec, seed=5).sample_grid(np.arange(0, 200, 0.01))
    b = RandomDisturbance(spec, seed=5).sample_grid(np.arange(0, 200, 0.01))
    c = RandomDisturbance(spec, seed=6).sample_grid(np.arange(0, 200, 0.01))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    spectrum = np.abs(np.fft.rfft(a[:, 0]))
    freqs = np.fft.rfftfreq(len(a), 0.01)
    in_band = spectrum[(freqs >= 0.09) & (freqs <= 2.05)].sum()
    assert in_band > 0.9 * spectrum.sum()
