"""``slung emulate --sensors``: the telemetry carries the issue-3 sensor models (``sim_bridge.plant.sensors``): white
noise of the preset's size, the accelerometer bias, the latency (+ jitter) in the sample stamps; seeded and
deterministic in lockstep. Real UDP on 127.0.0.1, lockstep flights of a hold controller.

Noise sizes are estimated from second differences of the 100 Hz telemetry (``std(x[k+1] - 2 x[k] + x[k-1]) / sqrt 6``
is the white-noise standard deviation; the hover's own motion over 20 ms is far smaller, as the ``ideal`` run shows).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
from emulator_helpers import Emu, fly_lockstep_hold

from estimators.model.vehicle import Vehicle
from sim_bridge.plant.sensors import SensorSuite, preset_spec

V = Vehicle()
STREAMS = ("ATTITUDE", "LOCAL_POSITION_NED", "HIGHRES_IMU", "DEBUG_VECT")
SEED = 3  # its accelerometer bias is large enough (> 0.1 m/s^2 on x and y) to be seen over a short hover


def _flight(sensors: str, seed: int, seconds: float) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]]:
    with Emu(
        "--lockstep", "--lockstep-grace", "1", "--est-ready", "0.2", "--sensors", sensors, "--seed", str(seed)
    ) as e:
        r = fly_lockstep_hold(e, seconds, V, collect=STREAMS)
        summary = e.stop()
    summary["start_ms"] = r["start_ms"]
    return r["messages"], summary


@pytest.fixture(scope="module")
def typical() -> tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]]:
    return _flight("px4-typical", SEED, 8.0)


def _noise_std(values: list[list[float]], skip: int = 200) -> np.ndarray:
    a = np.array(values)[skip:]
    return np.std(np.diff(a, 2, axis=0), axis=0) / math.sqrt(6.0)


def _columns(msgs: list[tuple[int, Any]], fields: tuple[str, ...]) -> list[list[float]]:
    return [[float(getattr(m, f)) for f in fields] for _, m in msgs]


def test_noise_matches_the_preset(typical: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]]) -> None:
    msgs, summary = typical
    assert summary["sensors"] == "px4-typical" and summary["mode"] == "OFFBOARD"
    pr = preset_spec("px4-typical")
    assert all(len(msgs[n]) >= 700 for n in STREAMS)
    sxy, sz, svxy, svz = pr.position.noise
    pos = _noise_std(_columns(msgs["LOCAL_POSITION_NED"], ("x", "y", "z", "vx", "vy", "vz")))
    assert pos == pytest.approx([sxy, sxy, sz, svxy, svxy, svz], rel=0.15)
    sa, sy, sr = pr.attitude.noise
    att = _noise_std(_columns(msgs["ATTITUDE"], ("roll", "pitch", "yaw", "rollspeed", "pitchspeed", "yawspeed")))
    assert att == pytest.approx([sa, sa, sy, sr, sr, sr], rel=0.15)
    sacc, sg = pr.imu.noise
    imu = _noise_std(_columns(msgs["HIGHRES_IMU"], ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro")))
    assert imu == pytest.approx([sacc, sacc, sacc, sg, sg, sg], rel=0.15)
    load = _noise_std(_columns(msgs["DEBUG_VECT"], ("x", "y")))
    assert load == pytest.approx([pr.load.noise[0]] * 2, rel=0.15)


def test_accelerometer_carries_the_bias_slung_sim_draws(
    typical: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]],
) -> None:
    msgs, summary = typical
    # the same draw as slung sim's sensor suite with the same seed (its first draw from the seeded generator)
    expected = SensorSuite("px4-typical", V, np.random.default_rng(SEED)).accel_bias
    assert summary["accel_bias_flu"] == pytest.approx(list(expected), abs=1e-15)
    bx, by = expected[0], -expected[1]  # FLU -> FRD
    assert min(abs(bx), abs(by)) > 0.1
    # in a level hold the mean horizontal specific force is 0: what the accelerometer reports is its bias
    acc = np.array(_columns(msgs["HIGHRES_IMU"], ("xacc", "yacc")))[300:]
    mean = acc.mean(axis=0)
    assert mean == pytest.approx([bx, by], abs=0.03)
    assert np.all(np.abs(mean) > 0.07)


def test_latency_and_jitter_are_in_the_sample_stamps(
    typical: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]],
) -> None:
    """Each message is sent at a step marker and stamped with its sample time, latency + U(0, jitter) earlier
    (on the 1 ms plant grid, rounded to the older step)."""
    msgs, _ = typical
    pr = preset_spec("px4-typical")
    for name, spec, stamp in (
        ("ATTITUDE", pr.attitude, lambda m: m.time_boot_ms),
        ("LOCAL_POSITION_NED", pr.position, lambda m: m.time_boot_ms),
        ("HIGHRES_IMU", pr.imu, lambda m: m.time_usec // 1000),
        ("DEBUG_VECT", pr.load, lambda m: m.time_usec // 1000),
    ):
        lags = [marker - stamp(m) for marker, m in msgs[name]]
        lo, hi = math.floor(spec.latency_s * 1000), math.ceil((spec.latency_s + spec.jitter_s) * 1000)
        assert lo <= min(lags) and max(lags) <= hi, name
        assert len(set(lags)) >= 2, name  # the jitter
        assert np.mean(lags) == pytest.approx(1000 * (spec.latency_s + spec.jitter_s / 2) + 0.5, abs=0.3), name
        stamps = [stamp(m) for _, m in msgs[name]]
        assert all(b > a for a, b in itertools.pairwise(stamps)), name  # never out of order


def test_ideal_is_the_truth_without_latency() -> None:
    msgs, summary = _flight("ideal", SEED, 3.0)
    assert summary["accel_bias_flu"] == [0.0, 0.0, 0.0]
    for name in ("ATTITUDE", "LOCAL_POSITION_NED"):
        assert all(marker == m.time_boot_ms for marker, m in msgs[name])
    pos = _noise_std(_columns(msgs["LOCAL_POSITION_NED"], ("x", "y", "z")), skip=100)
    assert pos[0] == 0.0 and pos[1] == 0.0 and pos[2] < 1e-4  # the level hold has no lateral motion at all
    att = _noise_std(_columns(msgs["ATTITUDE"], ("roll", "pitch")), skip=100)
    assert att[0] == 0.0 and att[1] == 0.0


def _wire(msgs: dict[str, list[tuple[int, Any]]], start_ms: int, until_ms: int) -> list[tuple[Any, ...]]:
    """Every field of every collected message, with the clock counted from the offboard entry (the only thing a
    wall clock decides: how long the emulator free-ran before the first setpoint)."""
    out = []
    for name in STREAMS:
        for marker, m in msgs[name]:
            if marker - start_ms > until_ms:
                continue
            fields = []
            for f in m.get_fieldnames():
                v = getattr(m, f)
                if f == "time_boot_ms":
                    v -= start_ms
                elif f == "time_usec":
                    v -= start_ms * 1000
                fields.append(v)
            out.append((marker - start_ms, name, tuple(fields)))
    return sorted(out, key=lambda r: (r[0], r[1]))


def test_same_seed_same_telemetry_other_seed_differs(
    typical: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]],
) -> None:
    """Lockstep: the same seed gives bit-identical telemetry values (float32 as sent), another seed other ones."""
    again, s2 = _flight("px4-typical", SEED, 3.0)
    other, s3 = _flight("px4-typical", SEED + 1, 3.0)
    until = again["ATTITUDE"][-1][0] - s2["start_ms"]
    a = _wire(typical[0], typical[1]["start_ms"], until)
    b = _wire(again, s2["start_ms"], until)
    c = _wire(other, s3["start_ms"], until)
    assert len(a) > 1000
    assert a == b
    assert len(c) == len(a) and sum(x[2] != y[2] for x, y in zip(a, c)) > 0.9 * len(a)
