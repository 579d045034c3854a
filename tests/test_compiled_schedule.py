"""The compiled sensor-record schedule (``offboard.harness.compiled.schedule``) equals the Python one on the scalar
``SensorSuite`` (``tests/schedule_reference.py``) array for array, and leaves the generator in the scalar path's state.

13 s runs (the sweep's default scenario: 1 + 4 + 8 s), at 1 kHz control (1 plant step per tick) and at 250 Hz
control (4 plant steps per tick); the presets as named and as the sweep scales them (noise x0.5..2, latency +0..20 ms:
some records then reach the filter after the blocks they update have moved on, and are dropped).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import schedule_reference

from estimators.kernels import ADVANCE, GYRO
from estimators.model.vehicle import load_vehicle
from offboard.harness import sweep
from offboard.harness.compiled import schedule as compiled
from offboard.harness.compiled.schedule import RunSchedule
from sim_bridge.plant.sensors import preset_spec

PLANT_DT = 0.001
DURATION_S = 13.0
#: (control_dt, substeps)
TIMINGS = [(0.001, 1), (0.004, 4)]
DELAY_S = 0.012  # the filter's default fusion horizon (estimators.filters.measured_kf)
VEHICLE = load_vehicle(None)  # the Python path's SensorSuite needs one (the schedule does not depend on it)


def n_ticks(control_dt: float) -> int:
    """Control ticks of a 13 s run (as offboard.harness.compiled.engine.simulate counts them)."""
    return math.floor(DURATION_S / control_dt + 1e-9) + 1


def assert_same(a: RunSchedule, b: RunSchedule) -> None:
    """Every array of the two schedules equal, with the same dtype and shape."""
    pairs = [
        (f"{name}[{k}]", x, y)
        for name in ("steps", "times", "noise")
        for k, (x, y) in enumerate(zip(getattr(a, name), getattr(b, name)))
    ]
    pairs += [(name, getattr(a, name), getattr(b, name)) for name in ("events", "payload", "bias")]
    assert len(a.steps) == len(b.steps) == 4
    for name, x, y in pairs:
        assert x.dtype == y.dtype and x.shape == y.shape, (name, x.dtype, y.dtype, x.shape, y.shape)
        assert np.array_equal(x, y), name


def both(preset: Any, seed: int, timing: tuple[float, int], **flags: Any) -> tuple[Any, Any]:
    """The Python and the compiled schedule of one run."""
    dt, substeps = timing
    args = (preset, VEHICLE, seed, n_ticks(dt), dt, PLANT_DT, substeps)
    kw = {"delay_s": DELAY_S, **flags}
    return schedule_reference.schedule(*args, **kw), compiled.schedule(*args, **kw)


def dropped(run: RunSchedule) -> int:
    """Records the filter never fused though later records of their kind were (late records)."""
    out = 0
    for code in (0, 1, 2, 3, GYRO):
        fused = run.payload[run.events[:, 2] == code]
        out += int(fused.max()) + 1 - len(fused) if len(fused) else 0
    return out


@pytest.mark.parametrize("timing", TIMINGS, ids=["1kHz", "250Hz"])
@pytest.mark.parametrize("name", ["px4-typical", "px4-fast", "ideal"])
def test_named_presets_give_the_python_schedule(name: str, timing: tuple[float, int]) -> None:
    for seed, load_sensor, fuse_gyro in ((3, True, False), (11, False, True)):
        py, nb = both(name, seed, timing, load_sensor=load_sensor, fuse_gyro=fuse_gyro)
        assert_same(nb, py)
        assert (len(py.steps[3]) > 0) == load_sensor  # what is compared: the cases differ as they should
        assert (py.events[:, 2] == GYRO).any() == fuse_gyro


@pytest.mark.parametrize("timing", TIMINGS, ids=["1kHz", "250Hz"])
@pytest.mark.parametrize("name", ["px4-typical", "px4-fast"])
def test_scaled_presets_give_the_python_schedule(name: str, timing: tuple[float, int]) -> None:
    """Noise and latency scaled as the sweep scales them, late records dropped by the filter included."""
    config = sweep.SweepConfig(sensors=name)
    cases = [(0.5, 0.0, 1, True, True), (2.0, 0.02, 0, True, False), (1.3, 0.01, 4, False, True)]
    drops = 0
    for noise, latency, seed, load_sensor, fuse_gyro in cases:
        preset = sweep.sensor_preset(config, {"sensor_noise": noise, "sensor_latency_s": latency})
        py, nb = both(preset, seed, timing, load_sensor=load_sensor, fuse_gyro=fuse_gyro)
        assert_same(nb, py)
        drops += dropped(py)
    if name == "px4-fast":  # the grid meets the filter's drop of late records (px4-fast, +10..20 ms)
        assert drops > 0


@pytest.mark.parametrize("timing", TIMINGS, ids=["1kHz", "250Hz"])
def test_slow_sensors_give_the_python_schedule_with_block_advances(timing: tuple[float, int]) -> None:
    """Streams slow enough (IMU 10 Hz, position 5 Hz) for the filter to advance blocks left 50 ms behind."""
    base = preset_spec("px4-typical")
    preset = base._replace(imu=base.imu._replace(rate_hz=10.0), position=base.position._replace(rate_hz=5.0))
    for seed, load_sensor in ((2, False), (9, True)):
        py, nb = both(preset, seed, timing, load_sensor=load_sensor, fuse_gyro=True)
        assert_same(nb, py)
        codes = py.events[:, 2]
        assert ((codes >= ADVANCE) & (codes < GYRO)).any()  # advances are met (codes ADVANCE..ADVANCE + 7)


def test_the_noise_is_drawn_and_scaled() -> None:
    """A sanity check of what is compared: the noise follows the preset's sigmas; ideal draws none."""
    _, nb = both("px4-typical", 7, TIMINGS[0], load_sensor=True, fuse_gyro=False)
    sxy = preset_spec("px4-typical").position.noise[0]
    assert 0.8 * sxy < np.std(nb.noise[0][:, 0]) < 1.2 * sxy
    assert np.all(nb.bias != 0.0)
    _, ideal = both("ideal", 7, TIMINGS[0], load_sensor=True, fuse_gyro=False)
    assert all(not n.any() for n in ideal.noise) and not ideal.bias.any()


def python_generator_state(preset: Any, seed: int, timing: tuple[float, int], load_sensor: bool) -> dict[str, Any]:
    """The state of the scalar path's generator after its sensors' calls of a 13 s run: the scalar
    ``SensorSuite.sample`` (values left out) called at every plant step, as ``offboard.harness.sim`` calls it."""
    dt, substeps = timing
    rng = np.random.default_rng(seed)
    suite = schedule_reference._DrySuite(preset, VEHICLE, rng, load_sensor=load_sensor)
    for tick in range(n_ticks(dt) - 1):
        for i in range(substeps):
            suite.sample(tick * dt + (i + 1) * PLANT_DT, None, None)
    return rng.bit_generator.state


@pytest.mark.parametrize("name", ["px4-typical", "ideal"])
def test_the_generator_is_left_in_the_scalar_paths_state(name: str) -> None:
    dt, substeps = TIMINGS[1]
    rng = np.random.default_rng(5)
    compiled.schedule_rng(
        name, rng, n_ticks(dt), dt, PLANT_DT, substeps, load_sensor=True, delay_s=DELAY_S, fuse_gyro=True
    )
    assert rng.bit_generator.state == python_generator_state(name, 5, TIMINGS[1], load_sensor=True)
    if name == "ideal":  # no noise, no phase, no bias: no draw at all
        assert rng.bit_generator.state == np.random.default_rng(5).bit_generator.state


def test_too_few_rows_are_reported_not_overrun() -> None:
    """The kernel counts the records and events it has no row for; the wrapper's capacities never meet it."""
    streams = compiled.stream_table(preset_spec("px4-fast"), True)
    out = compiled.schedule_kernel(
        np.random.default_rng(0), streams, True, 0.05, 1001, 0.001, 0.001, 1, True, DELAY_S, False, 10, 10
    )
    assert out[3][compiled.N_OVERFLOW] > 0
    rec_cap, ev_cap = compiled.capacities(streams, 13000, PLANT_DT)
    out = compiled.schedule_kernel(
        np.random.default_rng(0), streams, True, 0.05, 13001, 0.001, 0.001, 1, True, DELAY_S, False, rec_cap, ev_cap
    )
    assert out[3][compiled.N_OVERFLOW] == 0
