"""Throughput of ``slung sweep``'s compiled engine (``offboard.harness.compiled``) against the scalar path, measured in
the same process and the same run, and where a compiled tick goes.

1. the scalar path (``offboard.harness.sweep.run_one``: ``--scalar`` runs of the default file, filter, sensors, mixer);
2. the compiled engine (``offboard.harness.compiled.engine.run_batch``) on ``--runs`` runs, with its parts: the
   kernel flying the runs (``fly_run``), each run's record schedule, the rest (draws, constants, Python);
3. the compiled kernels one call at a time (ns per call, a numba loop around each): RK4 step, tension, each law,
   the true state; the filter's whole cost per tick follows from 3.

    python bench/bench_compiled.py [--runs 400] [--scalar 2] [--repeat 3]

Figures in CPU seconds (``time.process_time``; wall seconds beside them), the best of ``--repeat`` rounds, after a
warm-up that loads (or compiles) the kernels. One process, one core: ``slung sweep --workers 2`` runs two such
processes.
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np

from estimators.kernels import EST_SIZE
from estimators.model.vehicle import Vehicle
from offboard.control.compiled import laws as claws
from offboard.control.compiled.reference_row import REF_SIZE
from offboard.control.controllers import registry
from offboard.harness import sweep
from offboard.harness.compiled import engine
from offboard.harness.compiled import schedule as csched
from sim_bridge.plant.compiled import plant as cp

SIM_S = 13.0  # simulated seconds of one run of the default file


def _timed(f, *args):  # type: ignore[no-untyped-def]
    c0, w0 = time.process_time(), time.perf_counter()
    out = f(*args)
    return out, time.process_time() - c0, time.perf_counter() - w0


def paths(runs: int, scalar_runs: int, repeat: int) -> dict[str, dict[str, float]]:
    """Simulated seconds per CPU and wall second of each path (best of ``repeat``), and the compiled parts."""
    cfg = sweep.load_config(None)
    engine.run_batch(cfg, "smc", [0])  # load or compile the kernels; sample the reference once
    out: dict[str, dict[str, float]] = {}
    best: dict[str, tuple[float, float]] = {}
    for _ in range(repeat):
        for name, call, n in (
            ("scalar", lambda: [sweep.run_one(cfg, "smc", r) for r in range(scalar_runs)], scalar_runs),
            ("compiled", lambda: engine.run_batch(cfg, "smc", list(range(runs))), runs),
        ):
            _, c, w = _timed(call)
            if name not in best or c < best[name][0]:
                best[name] = (c, w)
            out[name] = {"runs": n, "per_cpu_s": n * SIM_S / best[name][0], "per_wall_s": n * SIM_S / best[name][1]}
    # the compiled engine's parts: the kernel alone, the schedules alone
    v = Vehicle()
    draws = [sweep.draw(cfg, r, v) for r in range(runs)]
    c0 = time.process_time()
    for d in draws:
        csched.schedule(
            sweep.sensor_preset(cfg, d),
            v,
            int(d["sensor_seed"]),
            13001,
            0.001,
            0.001,
            1,
            load_sensor=True,
            delay_s=0.012,
            fuse_gyro=False,
        )
    sched_s = time.process_time() - c0
    kernel_s = _kernel_seconds(cfg, runs)
    total = runs * SIM_S / out["compiled"]["per_cpu_s"]
    out["compiled_parts"] = {
        "kernel_ns_per_tick": kernel_s / (runs * 13000) * 1e9,
        "kernel_share": kernel_s / total,
        "schedule_share": sched_s / total,
        "schedule_ms_per_run": sched_s / runs * 1e3,
    }
    return out


def _kernel_seconds(cfg: sweep.SweepConfig, runs: int) -> float:
    """CPU seconds inside ``fly_run`` for the runs of ``engine.run_batch`` (the kernel wrapped and timed)."""
    spent = [0.0]
    fly = engine.fly_run

    def timed_fly(*args):  # type: ignore[no-untyped-def]
        c0 = time.process_time()
        fly(*args)
        spent[0] += time.process_time() - c0

    engine.fly_run = timed_fly  # type: ignore[assignment]
    try:
        engine.run_batch(cfg, "smc", list(range(runs)))
    finally:
        engine.fly_run = fly
    return spent[0]


@numba.njit
def _rk4_loop(x, u, p, work, n):  # type: ignore[no-untyped-def]
    trig = work[5, 0 : cp.TRIG_SIZE]
    cp.angle_trig(x, trig)
    for _ in range(n):  # as the engine steps: the attitude's sines kept from one step to the next
        cp.rk4_step_trig(x, u, p, 1e-3, work, trig)


@numba.njit
def _tension_loop(x, u, p, n):  # type: ignore[no-untyped-def]
    s = 0.0
    for _ in range(n):
        x[6] += 1e-12
        s += cp.tension(x, u, p)
    return s


@numba.njit
def _law_loop(code, c, K, mem, est, ref, uo, n):  # type: ignore[no-untyped-def]
    s = 0
    for i in range(n):
        est[0] += 1e-12
        s += claws.law_step(code, c, K, mem, i * 1e-3, 1e-3, est, ref, uo)
    return s


@numba.njit
def _truth_loop(x, out, n):  # type: ignore[no-untyped-def]
    for _ in range(n):
        x[12] += 1e-15
        cp.truth_state(x, 0.3, 9.8, 0.03, out)


def kernels(n: int = 200_000) -> dict[str, float]:
    """ns per call of the plant's and the laws' kernels (a hovering state; best of three loops of ``n`` calls)."""
    v = Vehicle()
    p = cp.plant_constants(v)
    x = np.zeros(18)
    x[2], x[6], x[7], x[14], x[15] = 2.0, 0.05, 0.02, -1.0, 0.1
    u = np.zeros(13)
    u[0] = (v.mass_vehicle + v.mass_load) * v.gravity
    est, ref, uo = np.zeros(EST_SIZE), np.zeros(REF_SIZE), np.zeros(4)
    est[12] = ref[14] = 2.0
    params = registry.smc_params(v)
    cases: dict[str, tuple] = {
        "rk4_step": (_rk4_loop, x, u, p, np.empty((6, 18))),
        "tension": (_tension_loop, x, u, p),
        "truth_state": (_truth_loop, x.copy(), np.zeros(EST_SIZE)),
    }
    for law in ("smc", "cascade", "swing-feedback", "lqr"):
        code, c, K = claws.law_constants(law, v, params)
        cases[f"law {law}"] = (_law_loop, code, c, K, claws.law_memory(code, c), est.copy(), ref, uo)
    out = {}
    for name, (f, *args) in cases.items():
        f(*args, 10)
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            f(*args, n)
            best = min(best, (time.perf_counter() - t0) / n * 1e9)
        out[name] = best
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=400, help="runs of the compiled engine per round")
    ap.add_argument("--scalar", type=int, default=2, help="runs of the scalar path per round")
    ap.add_argument("--repeat", type=int, default=3, help="rounds (the best is kept)")
    args = ap.parse_args()
    r = paths(args.runs, args.scalar, args.repeat)
    sc = r["scalar"]["per_cpu_s"]
    for name in ("scalar", "compiled"):
        f = r[name]
        print(
            f"{name:<9} {f['runs']:>5} runs of 13 s: {f['per_cpu_s']:8.1f} simulated s per CPU s "
            f"({f['per_wall_s']:.1f} per wall s), {f['per_cpu_s'] / sc:6.1f}x the scalar path"
        )
    parts = r["compiled_parts"]
    print(
        f"compiled parts: the kernel {parts['kernel_ns_per_tick']:.0f} ns per run and tick "
        f"({100 * parts['kernel_share']:.0f} % of the engine's CPU), the record schedule "
        f"{parts['schedule_ms_per_run']:.2f} ms per run ({100 * parts['schedule_share']:.0f} %)"
    )
    print("compiled kernels, ns per call:")
    for name, ns in kernels().items():
        print(f"  {name:<20} {ns:7.0f}")


if __name__ == "__main__":
    main()
