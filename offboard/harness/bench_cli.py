"""``slung bench``: how fast the plant, the reference, the controller, the estimator and a whole run are.

Reports medians and 99th percentiles of per-call times (microseconds) and the real-time factor of the paper
scenario at a 1 kHz controller, plus a baseline measured in the same run: the same plant integrated the way
many Python simulators do it (``scipy.integrate.solve_ivp`` RK45 over each 1 ms step). It never fails on a
figure: machines are shared and noisy, so it only reports.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from estimators.model.flatness import flat_constants
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.scenarios import make_scenario
from offboard.harness import sim as sim_mod
from offboard.harness.sim import truth_control_state
from offboard.outputs import prepare_output_dir, write_json_atomic
from sim_bridge.plant import dynamics


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``slung bench``."""
    p.add_argument("--repeat", type=int, default=20000, metavar="N", help="calls per micro-benchmark (default 20000)")
    p.add_argument("--runs", type=int, default=3, metavar="N", help="whole paper runs to time (default 3)")
    p.add_argument("--estimator", action="store_true", help="also time the Kalman filter per control tick")
    p.add_argument("--out", metavar="DIR", help="also write bench.json into this folder")


def _per_call(fn: Callable[[int], Any], n: int) -> dict[str, float]:
    """Time ``fn(i)`` for i in range(n), one call at a time; microseconds."""
    times = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        t0 = clock()
        fn(i)
        times[i] = clock() - t0
    us = times / 1000.0
    return {"median_us": float(np.median(us)), "p99_us": float(np.percentile(us, 99)), "calls": n}


def measure(repeat: int = 20000, runs: int = 3, with_estimator: bool = False) -> dict[str, Any]:
    """All figures as a dictionary (see module docstring)."""
    vehicle = Vehicle()
    p = dynamics.plant_params(vehicle)
    params = smc.ControllerParams.for_vehicle(vehicle)
    scenario = make_scenario("paper")
    ref = scenario.reference
    k = flat_constants(vehicle)
    x = dynamics.make_state(
        position=(0.1, -0.2, 1.5),
        euler=(0.05, -0.03, 0.4),
        euler_rate=(0.1, 0.2, -0.1),
        cable=(0.1, 0.05, -1.0),
        cable_rate=(0.2, -0.1, 0.0),
    )
    u = dynamics.make_input(7.0, (0.01, -0.02, 0.003), (0.1, 0.2, 0.3))
    state = truth_control_state(x, k)
    samples = [ref.sample(10.0 + 1e-3 * i) for i in range(256)]
    mem = smc.ControllerMemory(t=0.0)

    out: dict[str, Any] = {"micro": {}}
    out["micro"]["plant_rk4_step"] = _per_call(lambda i: dynamics.rk4_step(x, u, p, 1e-3), repeat)
    out["micro"]["plant_derivative"] = _per_call(lambda i: dynamics.derivative(0.0, x, u, p), repeat)
    out["micro"]["reference_sample"] = _per_call(lambda i: ref.sample(10.0 + 1e-3 * i), repeat)
    out["micro"]["controller_step"] = _per_call(
        lambda i: smc.step(
            1e-3 * (i + 1),
            state,
            samples[i & 255].fx,
            samples[i & 255].fy,
            samples[i & 255].z,
            samples[i & 255].psi,
            mem,
            params,
        ),
        repeat,
    )

    from scipy.integrate import solve_ivp

    def baseline(i: int) -> None:
        solve_ivp(lambda t, y: dynamics.derivative(t, y, u, p), (0.0, 1e-3), x, method="RK45")

    out["micro"]["baseline_solve_ivp_rk45_step"] = _per_call(baseline, max(200, repeat // 20))
    out["plant_speedup_vs_baseline"] = (
        out["micro"]["baseline_solve_ivp_rk45_step"]["median_us"] / out["micro"]["plant_rk4_step"]["median_us"]
    )

    if with_estimator:
        out["micro"]["estimator_tick"] = _estimator_tick(vehicle, repeat)

    walls = []
    for _ in range(runs):
        log = sim_mod.run(scenario, vehicle, params, sim_mod.SimConfig())
        walls.append(log.wall_time)
    out["paper_run"] = {
        "simulated_s": scenario.duration,
        "control_rate_hz": 1000.0,
        "plant_rate_hz": 1000.0,
        "wall_s_median": statistics.median(walls),
        "wall_s_all": walls,
        "realtime_factor": scenario.duration / statistics.median(walls),
    }
    return out


def _estimator_tick(vehicle: Vehicle, repeat: int) -> dict[str, float]:
    """Per-tick cost of the Kalman filter fed by the px4-typical sensors (measurements + estimate)."""
    from estimators.filters.factory import make_estimator
    from sim_bridge.plant.sensors import SensorSuite

    p = dynamics.plant_params(vehicle)
    sensors = SensorSuite("px4-typical", vehicle, np.random.default_rng(0), load_sensor=False)
    est = make_estimator("kf", vehicle, load_sensor=False, rate_hz=250.0)
    x = dynamics.make_state(position=(0.0, 0.0, 1.0))
    u = dynamics.hover_input(p)
    est.initialize(0.0, truth_control_state(x, flat_constants(vehicle)))
    batches = []
    for i in range(repeat):
        batches.append(sensors.sample((i + 1) * 0.004, x, u))

    def tick(i: int) -> None:
        for m in batches[i]:
            est.push(m)
        est.push_command((i + 1) * 0.004, u[0], (0.0, 0.0, 0.0))
        est.estimate((i + 1) * 0.004)

    return _per_call(tick, repeat)


def format_report(r: dict[str, Any]) -> str:
    """A plain table of the figures."""
    lines = [f"{'what':<32} {'median us':>10} {'p99 us':>10}", "-" * 54]
    for name, m in r["micro"].items():
        lines.append(f"{name:<32} {m['median_us']:>10.1f} {m['p99_us']:>10.1f}")
    lines.append("-" * 54)
    lines.append(f"plant RK4 step vs solve_ivp(RK45) per step: {r['plant_speedup_vs_baseline']:.1f}x faster")
    pr = r["paper_run"]
    lines.append(
        f"paper scenario, {pr['simulated_s']:.0f} s at 1 kHz (plant + reference + controller + logging): "
        f"{pr['wall_s_median']:.2f} s wall, {pr['realtime_factor']:.1f}x real time"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Entry point of ``slung bench``."""
    from estimators.errors import UserError

    if args.repeat < 100 or args.runs < 1:
        raise UserError("--repeat must be >= 100 and --runs >= 1")
    out_dir = prepare_output_dir(args.out) if args.out else None
    r = measure(args.repeat, args.runs, args.estimator)
    print(format_report(r))
    if out_dir is not None:
        write_json_atomic(out_dir / "bench.json", r)
    else:
        print(json.dumps({"realtime_factor": r["paper_run"]["realtime_factor"]}))
    return 0
