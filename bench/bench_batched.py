"""Throughput of the batched sweep path (``offboard.harness.batched``) against its cost model, in this process.

1. numpy's cost per call of the operations the path is made of, by array length: the fixed cost (Python and
   numpy dispatch) and the cost per element;
2. the batched path (filter, sensors, mixer, sliding-mode law, as ``slung sweep``'s default engine) for batches
   of ``--sizes`` runs of a ``--seconds`` long sweep run: simulated seconds per CPU second, the part spent in the
   per-run record schedule, and the numpy calls per tick (counted with a profiler on a short separate run);
3. the same runs one by one through the scalar path (``offboard.harness.sim.run``), per CPU second.

    python bench/bench_batched.py [--sizes 10,100,500,2000] [--seconds 2]

CPU seconds (``time.process_time``), so that the figures hold on a shared machine as well as they can; wall
seconds beside them.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from dataclasses import replace

import numpy as np

from estimators.filters.measured_kf import MeasuredTuning
from estimators.model.vehicle import Vehicle
from offboard.control.controllers import registry
from offboard.harness import batched, batched_sensors, sweep


def per_call_costs() -> list[tuple[str, int, float]]:
    """(operation, length, microseconds per call) for a multiply, a where, a sine and a gather."""
    rng = np.random.default_rng(0)
    out = []
    for n in (1, 10, 100, 1000, 10000):
        a, b = rng.random(n), rng.random(n)
        m = a > 0.5
        idx = rng.integers(0, n, max(n // 10, 1))
        for name, f in (
            ("a * b", lambda a=a, b=b: a * b),
            ("where(m, a, b)", lambda a=a, b=b, m=m: np.where(m, a, b)),
            ("sin(a)", lambda a=a: np.sin(a)),
            ("a[idx] (n/10)", lambda a=a, idx=idx: a[idx]),
        ):
            reps = max(2000, 200000 // n)
            c0 = time.process_time()
            for _ in range(reps):
                f()
            out.append((name, n, (time.process_time() - c0) / reps * 1e6))
    return out


def _runs(n: int, seconds: float, hold_s: float = 0.3) -> tuple:
    """The default sweep's first ``n`` runs, moves of ``seconds - 1.3`` s (at least 0.2) then ``hold_s`` s: the
    sweep's configuration, the nominal vehicle and per run its vehicle, scenario, sensor preset, sensor seed."""
    v = Vehicle()
    cfg = replace(sweep.load_config(None), move_time_s=max(seconds - 1.3, 0.2), hold_s=hold_s)
    draws = [sweep.draw(cfg, r, v) for r in range(n)]
    vehicles = [sweep.plant_vehicle(v, d) for d in draws]
    scs = [sweep.scenario(cfg, d) for d in draws]
    presets = [sweep.sensor_preset(cfg, d) for d in draws]
    seeds = [int(d["sensor_seed"]) for d in draws]
    return cfg, v, vehicles, scs, presets, seeds


def _simulate(v: Vehicle, vehicles: list, scs: list, presets: list, seeds: list) -> None:
    """The runs through the batched engine as the sweep flies them (smc, filter, mixer), nothing logged."""
    batched.simulate(
        scs,
        vehicles,
        registry.smc_params(v),
        log_every=0,
        estimator="kf",
        actuators="mixer",
        sensors=presets,
        seeds=seeds,
    )


def batched_speed(n: int, seconds: float) -> dict[str, float]:
    _, v, vehicles, scs, presets, seeds = _runs(n, seconds)
    n_ticks = round(scs[0].duration * 1000) + 1
    c0 = time.process_time()
    for b in range(min(n, 20)):  # the per-run schedule alone (the loop makes it for every run again)
        batched_sensors.schedule(
            *(presets[b], vehicles[b], seeds[b], n_ticks, 0.001, 0.001, 1),
            load_sensor=True,
            delay_s=0.012,
            fuse_gyro=MeasuredTuning().fuse_gyro,
        )
    sched = (time.process_time() - c0) / min(n, 20)
    c0, w0 = time.process_time(), time.perf_counter()
    _simulate(v, vehicles, scs, presets, seeds)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    sim_s = n * (n_ticks - 1) * 0.001
    return {
        "runs": n,
        "sim_s": sim_s,
        "per_cpu_s": sim_s / cpu,
        "per_wall_s": sim_s / wall,
        "schedule_share": n * sched / cpu,
    }


def numpy_calls_per_tick(n: int) -> float:
    """numpy function and ufunc calls per tick of the batched loop (0.3 s runs, a profiler counting)."""
    _, v, vehicles, scs, presets, seeds = _runs(n, 1.5, hold_s=0.1)
    prof = cProfile.Profile()
    prof.enable()
    _simulate(v, vehicles, scs, presets, seeds)
    prof.disable()
    st = pstats.Stats(prof)
    calls = 0
    for (file, _, name), (_, ncalls, *_rest) in st.stats.items():  # type: ignore[attr-defined]
        if (
            "numpy" in file
            or name.startswith("<method '")
            or "ufunc" in name
            or name.startswith("<built-in method numpy")
        ):
            calls += ncalls
    n_ticks = round(scs[0].duration * 1000) + 1
    return calls / n_ticks


def scalar_speed(seconds: float, n: int = 3) -> float:
    cfg = _runs(n, seconds)[0]
    cfg = replace(cfg, estimator="kf", engine="scalar")
    c0 = time.process_time()
    sim_s = sum(sweep.run_one(cfg, "smc", r)["sim_s"] for r in range(n))
    return sim_s / (time.process_time() - c0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="10,100,500,2000", help="batch sizes (runs)")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per run")
    args = ap.parse_args()
    print("numpy cost per call (us), by array length:")
    costs = per_call_costs()
    for name in dict.fromkeys(c[0] for c in costs):
        row = "  ".join(f"{n:>5}: {us:7.2f}" for nm, n, us in costs if nm == name)
        print(f"  {name:<16} {row}")
    calls = numpy_calls_per_tick(100)
    print(
        f"numpy functions called per tick of the batched loop (100 runs; arithmetic operators not counted): {calls:.0f}"
    )
    print(f"scalar path, filter and mixer: {scalar_speed(args.seconds):.1f} simulated s per CPU s")
    for n in (int(s) for s in args.sizes.split(",")):
        r = batched_speed(n, args.seconds)
        print(
            f"batched, {n:>5} runs: {r['per_cpu_s']:7.1f} simulated s per CPU s ({r['per_wall_s']:.1f} per wall s); "
            f"record schedule {100 * r['schedule_share']:.0f} % of it"
        )


if __name__ == "__main__":
    main()
