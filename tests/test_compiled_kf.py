"""The compiled measured-input filter (``estimators.filters.compiled.kf``) against the scalar filter
(``estimators.filters.measured_kf.MeasuredKalmanEstimator``): drawn runs of the default sweep file, their drawn sensors
with noise and latency (late records dropped), the mixer and the sliding-mode law, flown by the compiled engine and by
the scalar path (``offboard.harness.sim.run``) with the filter set up as each case says (the cable sensor or the gyro,
the external acceleration fed forward with tight gates quick to reopen, fast or slow telemetry whose blocks the
schedule advances): the plant's trajectories and every tick's estimate agree to 1e-9.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from sweep_helpers import short_file

from estimators.filters.compiled.kf import kf_constants, kf_new_state
from estimators.filters.measured_kf import MeasuredTuning
from estimators.model.vehicle import Vehicle
from offboard.control.controllers import registry
from offboard.harness import sim, sweep
from offboard.harness.compiled import engine
from offboard.logs.runlog import SimConfig
from sim_bridge.plant.sensors import Preset, preset_spec

V = Vehicle()


def _fast(p: Preset) -> Preset:
    """The drawn suite at ``px4-fast``'s rates (position 100 Hz, attitude, IMU and cable angle 250 Hz)."""
    fast = preset_spec("px4-fast")
    streams = ("position", "attitude", "imu", "load")
    return p._replace(**{k: getattr(p, k)._replace(rate_hz=getattr(fast, k).rate_hz) for k in streams})


def _slow(p: Preset) -> Preset:
    """The drawn suite with 10 Hz position and IMU telemetry: blocks left behind for more than 0.05 s (the schedule's
    block advances), an acceleration input that goes stale between samples."""
    return p._replace(position=p.position._replace(rate_hz=10.0), imu=p.imu._replace(rate_hz=10.0))


#: the flights replayed: (cable-angle sensor, the filter's tuning, what becomes of the drawn sensor suite)
CASES: dict[str, tuple[bool, MeasuredTuning, Callable[[Preset], Preset] | None]] = {
    "default": (True, MeasuredTuning(), None),
    "gyro, no cable sensor": (False, MeasuredTuning(fuse_gyro=True), None),
    # the smc row's tuning (registry.filter_tuning) at 250 Hz, without the thrust window that keeps the height law's
    # thrust steps from being refused as the acceleration input, with a tight gate quick to reopen: refusals in a row
    "feed-forward, tight gates, fast": (
        True,
        MeasuredTuning(external_feedforward=True, thrust_explains_jumps=False, gate_probability=0.99, gate_reopen=1),
        _fast,
    ),
    "slow telemetry": (False, MeasuredTuning(), _slow),
}


def _short_file(tmp: Path) -> Path:
    """The default sweep file with a 1 s move and a 0.5 s hold, the filter in the loop (as tests/test_sweep.py)."""
    return short_file(tmp, "compiled", "kf", move=1.0, hold=0.5, gust_start=(0.5, 3.0))


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_the_compiled_filter_gives_the_scalar_filters_estimates(tmp_path: Path, case: str) -> None:
    """Three drawn runs with each case's filter and telemetry: the compiled engine's plant trajectories and its
    filter's estimate of the flat outputs at every control tick equal the scalar path's to 1e-9; the estimate is a
    real one (not the true state), and the feed-forward case's branch acts (its estimate moves without it)."""
    load_sensor, tuning, suite = CASES[case]
    cfg = sweep.load_config(_short_file(tmp_path))
    draws = [sweep.draw(cfg, r, V) for r in range(3)]
    assert max(d["sensor_latency_s"] for d in draws) > 0.006  # a run's positions come past the 12 ms horizon
    vehicles = [sweep.plant_vehicle(V, d) for d in draws]
    scs = [sweep.scenario(cfg, d) for d in draws]
    presets = [sweep.sensor_preset(cfg, d) for d in draws]
    if suite is not None:
        presets = [suite(p) for p in presets]
    seeds = [int(d["sensor_seed"]) for d in draws]
    params = registry.smc_params(V)
    kw = {"estimator": "kf", "actuators": "mixer", "sensors": presets, "seeds": seeds, "load_sensor": load_sensor}
    log = engine.simulate(scs, vehicles, params, tuning=tuning, **kw)
    for b in range(3):
        sim_cfg = SimConfig(
            estimator="kf", sensors=cfg.sensors, actuators="mixer", seed=seeds[b], load_sensor=load_sensor
        )
        ref = sim.run(
            scs[b],
            vehicles[b],
            params,
            sim_cfg,
            controller=registry.make("smc", V),
            sensor_preset=presets[b],
            command_lag=True,
            tuning=tuning,
        )
        assert ref.data.shape[0] == log["x"].shape[0]
        np.testing.assert_allclose(log["x"][:, :, b], ref.data[:, 1:19], rtol=0.0, atol=1e-9)
        for col in ("est_Fx0", "est_Fy0"):
            np.testing.assert_allclose(log[col][:, b], ref.column(col), rtol=0.0, atol=1e-9)
        assert np.abs(ref.column("est_Fx0")).max() > 1e-3  # a real estimate, not the true state
    if tuning.external_feedforward:
        off = engine.simulate(scs, vehicles, params, tuning=replace(tuning, external_feedforward=False), **kw)
        assert np.abs(off["est_Fx0"] - log["est_Fx0"]).max() > 1e-6


def test_constants_follow_the_tuning_and_refuse_a_vehicle_without_a_load() -> None:
    """Every constant slot is filled (NaN-free), the thrust window follows the control rate, a nominal vehicle
    without a load is refused, and so is a tuning without the commanded tilt input
    (the kernels always take it)."""
    from dataclasses import replace

    from estimators.filters.compiled.kf import C_GATE_REOPEN, C_N_THRUST

    c = kf_constants(V, MeasuredTuning(gate_reopen=7), load_sensor=True, rate_hz=250.0)
    assert np.isfinite(c).all()
    assert c[C_N_THRUST] == 25 and c[C_GATE_REOPEN] == 7
    f, n = kf_new_state(c)
    assert f.dtype == np.float64 and n.dtype == np.int64 and f.size > 25
    with pytest.raises(ValueError, match="load"):
        kf_constants(replace(V, mass_load=0.0), MeasuredTuning(), load_sensor=False)
    # a tuning the kernels cannot fly (no commanded tilt input) is refused, not flown as another filter
    with pytest.raises(ValueError, match="tilt_command"):
        kf_constants(V, MeasuredTuning(tilt_command=False), load_sensor=True)
    kf_constants(V, MeasuredTuning(), load_sensor=True)
