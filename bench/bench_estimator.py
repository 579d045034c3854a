"""Cost of the Kalman estimator per control tick, both modes (with and without the cable-angle sensor).

A hover run with an initial swing and small sinusoidal commands is simulated once (plant + ``px4-typical``
sensors); its measurement stream and commands are then replayed through a fresh estimator, timing for each
control tick everything the estimator does in that tick: ``push`` of the measurements delivered since the
previous tick, ``estimate(t)`` and ``push_command``. Prints median and p99 in microseconds, and those of the
read-outs the live loop logs after each tick (``sigmas()`` and ``innovations()``, timed on their own).

Usage: ``python bench/bench_estimator.py [--rate HZ] [--seconds S] [--sensors PRESET]``
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from estimators.filters.factory import make_estimator
from estimators.model.cable import cable_from_planar
from estimators.model.control_state import ControlState
from estimators.model.flatness import flat_constants, truth_control_state
from estimators.model.vehicle import Vehicle
from sim_bridge.plant import dynamics
from sim_bridge.plant.sensors import SensorSuite


def record(rate: float, seconds: float, preset: str, seed: int = 0) -> tuple[list, ControlState]:
    """Simulate once; return per tick (t, measurements delivered before the tick, command) and the start."""
    v = Vehicle()
    p = dynamics.plant_params(v)
    k = flat_constants(v)
    r, rd = cable_from_planar(0.15, 0.08)
    x = dynamics.make_state(cable=r, cable_rate=rd)
    sensors = SensorSuite(preset, v, np.random.default_rng(seed), load_sensor=True)
    plant_dt = 0.001
    sub = max(1, round(1.0 / (rate * plant_dt)))
    ticks = []
    pending: list = []
    for i in range(int(seconds * rate)):
        t = i * sub * plant_dt
        thrust = v.hover_thrust + 0.3 * math.sin(2.0 * t)
        tau = (0.002 * math.sin(3.0 * t), 0.002 * math.cos(2.5 * t), 0.001 * math.sin(t))
        ticks.append((t, pending, thrust, tau))
        pending = []
        u = dynamics.make_input(thrust, tau)
        for j in range(sub):
            x = dynamics.rk4_step(x, u, p, plant_dt)
            pending.extend(sensors.sample(t + (j + 1) * plant_dt, x, u))
    return ticks, truth_control_state(dynamics.make_state(cable=r, cable_rate=rd), k)


def time_ticks(ticks: list, start: ControlState, rate: float, load_sensor: bool) -> tuple[np.ndarray, np.ndarray]:
    """Seconds spent in the estimator at each tick, and in its read-outs for the log after it."""
    est = make_estimator("kf", Vehicle(), load_sensor=load_sensor, rate_hz=rate)
    est.initialize(0.0, start)
    out = np.empty(len(ticks))
    reads = np.empty(len(ticks))
    clock = time.perf_counter
    for i, (t, ms, thrust, tau) in enumerate(ticks):
        t0 = clock()
        for m in ms:
            est.push(m)
        est.estimate(t)
        est.push_command(t, thrust, tau)
        t1 = clock()
        est.sigmas()
        est.innovations()
        reads[i] = clock() - t1
        out[i] = t1 - t0
    return out, reads


def time_ticks_ab(ticks: list, start: ControlState, rate: float, load_sensor: bool) -> tuple[np.ndarray, np.ndarray]:
    """Seconds per tick of this filter and of the frozen original, run alternately on the same ticks."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from kf_reference import ReferenceKalmanEstimator

    ests = (
        make_estimator("kf", Vehicle(), load_sensor=load_sensor, rate_hz=rate),
        ReferenceKalmanEstimator(Vehicle(), load_sensor=load_sensor, rate_hz=rate),
    )
    for est in ests:
        est.initialize(0.0, start)
    out = np.empty((2, len(ticks)))
    clock = time.perf_counter
    for i, (t, ms, thrust, tau) in enumerate(ticks):
        for k in (i % 2, 1 - i % 2):  # alternate which runs first
            est = ests[k]
            t0 = clock()
            for m in ms:
                est.push(m)
            est.estimate(t)
            est.push_command(t, thrust, tau)
            out[k, i] = clock() - t0
    return out[0], out[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=200.0, help="control rate, Hz (default 200)")
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds (default 20)")
    ap.add_argument("--sensors", default="px4-typical", help="sensor preset (default px4-typical)")
    ap.add_argument("--reference", action="store_true", help="also time the original filter, interleaved")
    args = ap.parse_args(argv)
    ticks, start = record(args.rate, args.seconds, args.sensors)
    n_meas = sum(len(t[1]) for t in ticks)
    print(
        f"estimator cost per control tick: {len(ticks)} ticks at {args.rate:g} Hz, sensors {args.sensors}, "
        f"{n_meas / len(ticks):.2f} measurements per tick"
    )
    for load_sensor in (True, False):
        mode = "with cable-angle sensor" if load_sensor else "sensorless             "
        if args.reference:
            time_ticks_ab(ticks[: len(ticks) // 4], start, args.rate, load_sensor)  # warm-up
            new, ref = (a * 1e6 for a in time_ticks_ab(ticks, start, args.rate, load_sensor))
            for label, dt in (("this filter", new), ("original   ", ref)):
                print(
                    f"  {mode} {label}: median {np.median(dt):6.1f} us   p99 {np.percentile(dt, 99):6.1f} us   "
                    f"mean {dt.mean():6.1f} us"
                )
            print(
                f"  {mode} speed-up: median {np.median(ref) / np.median(new):.2f}x, "
                f"p99 {np.percentile(ref, 99) / np.percentile(new, 99):.2f}x, mean {ref.mean() / new.mean():.2f}x"
            )
            continue
        time_ticks(ticks[: len(ticks) // 4], start, args.rate, load_sensor)  # warm-up (caches, allocator)
        dt, reads = (a * 1e6 for a in time_ticks(ticks, start, args.rate, load_sensor))
        print(
            f"  {mode}: median {np.median(dt):6.1f} us   p99 {np.percentile(dt, 99):6.1f} us   max {dt.max():7.1f} us"
        )
        print(
            f"  {mode}  read-outs for the log (sigmas, innovations): median {np.median(reads):6.1f} us   "
            f"p99 {np.percentile(reads, 99):6.1f} us"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
