"""Real-time loop benchmark: ``slung fly`` against ``slung emulate --realtime`` over UDP on 127.0.0.1.

For each rate (default 250 and 500 Hz) the emulator runs as its own process, the loop flies the ``hover``
scenario for ``--duration`` seconds (default 60) with the Kalman filter, and the loop statistics are printed:
achieved rate, compute time (tick start to setpoint written) p50 / p99, of which the estimator, telemetry-to-
setpoint latency p50 / p99, and missed deadlines (a setpoint more than 1.5 periods after the previous one, or a
compute time above one period). The machine's load average is printed beside them: the emulator's 1 kHz plant and
the loop share the cores with whatever else runs.

    python bench/bench_loop.py [--rates 250 500] [--duration 60] [--rt-priority N] [--pin] [--lockstep] [--out DIR]

``--lockstep`` runs the emulator and the loop in lockstep (``slung emulate --lockstep``, one control period of
simulated time per setpoint) instead of in real time: the loop does the same work per tick and its compute time is
measured the same way, but no deadline can be missed, so the figure can be taken on a loaded machine where the
real-time emulator falls behind and the loop's stale-telemetry watchdog ends the flight (``missed`` is then 0 by
construction; the achieved rate is that of vehicle time).

The emulator runs under ``SCHED_BATCH`` (``--emulator-wakeup``: under normal scheduling): on a vehicle the autopilot is
another computer, and the setpoint's ``sendto`` costs the loop 20-40 us; here the emulator, woken by that datagram
on a shared core, preempts the loop inside its ``sendto`` and runs its own step first, which billed the loop
330 us median (p99 3.8 ms) of the emulator's work in the compute time (measured 2026-12-02 at load 7.8, lockstep:
``send`` 333 us median normal, 40 us batch). A ``SCHED_BATCH`` task never preempts on wake-up; it still gets its
share of the CPU.

After each flight the machine's own spread is measured in the same run (:func:`machine_baseline`): a constant tick
(fixed pure-Python work plus one ``sendto``) sized to the loop's median compute, at the same rate and priority; its
p99 / p50 is printed beside the loop's. On a shared virtual machine a tick that never changes has a p99 1.2-2.7
times its median (docs/usage-fly-demo.md), which bounds what any p99 figure taken here can show.

``--pin`` puts the emulator on the last CPU and the loop on the others (``os.sched_setaffinity``; restored after): on a
vehicle the autopilot is another computer, while here its 1 kHz plant otherwise shares the loop's core and caches.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from emulator_helpers import emulator_process  # noqa: E402 - after the path set-up

from offboard.harness.demo_cli import free_udp_port  # noqa: E402


def one(
    rate: float,
    duration: float,
    out: Path,
    rt_priority: int = 0,
    pin: bool = False,
    status: bool = False,
    lockstep: bool = False,
    emulator_batch: bool = True,
) -> dict:
    """One flight; ``status``: with the live status display (``offboard.flight.status``) on stderr, as ``slung fly`` on
    a terminal shows it (bench/bench_status.py compares the two); ``lockstep``: emulator and loop in lockstep."""
    from offboard.flight.fly_cli import fly
    from offboard.harness.demo_cli import configure

    port = free_udp_port()
    summary = out / f"emulator-{rate:g}.json"
    emu = emulator_process(
        port,
        *(("--lockstep", "--lockstep-period", repr(1.0 / rate)) if lockstep else ("--realtime",)),
        "--summary",
        str(summary),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    if emulator_batch:
        os.sched_setscheduler(emu.pid, os.SCHED_BATCH, os.sched_param(0))
    cpus = sorted(os.sched_getaffinity(0))
    pinned = pin and len(cpus) >= 2
    if pinned:
        os.sched_setaffinity(emu.pid, {cpus[-1]})
        os.sched_setaffinity(0, set(cpus[:-1]))
    time.sleep(1.5)  # let the emulator import and bind before the loop (maybe at real-time priority) starts
    p = argparse.ArgumentParser()
    configure(p)
    args = p.parse_args(
        [
            "--scenario",
            "hover",
            "--duration",
            str(duration),
            "--rate",
            str(rate),
            "--no-figures",
            "--rt-priority",
            str(rt_priority),
            "--out",
            str(out / f"loop-{rate:g}-p{rt_priority}{'-status' if status else ''}"),
        ]
    )
    args.connect, args.trajectory = f"udpin:127.0.0.1:{port}", None
    load0 = os.getloadavg()
    try:
        m, _ = fly(args, lockstep=lockstep, quiet=not status)
    finally:
        emu.send_signal(signal.SIGTERM)
        emu.wait(timeout=10)
        if pinned:
            os.sched_setaffinity(0, set(cpus))
    lp = m["loop"]
    return {
        "rate_hz": rate,
        "rt_priority": rt_priority,
        "pinned": pinned,
        "lockstep": lockstep,
        "emulator_batch": emulator_batch,
        "ended_by": m["flight"]["ended_by"],
        "load_before": load0[0],
        "load_after": os.getloadavg()[0],
        **{
            k: lp[k]
            for k in (
                "rate_hz_achieved",
                "ticks",
                "elapsed_s",
                "compute_us_p50",
                "compute_us_p99",
                "estimator_us_p50",
                "estimator_us_p99",
                "latency_us_p50",
                "latency_us_p99",
                "missed_deadlines",
                "missed_fraction",
                "deadline_ticks",
            )
        },
    }


def _constant_work(n: int) -> float:
    """A fixed amount of pure-Python arithmetic (``n`` multiply-adds): the same instructions every call."""
    acc = 0.0
    for i in range(n):
        acc += i * 0.5
    return acc


def machine_baseline(rate: float, ticks: int, median_us: float) -> dict[str, float]:
    """What this machine does to a tick that never changes: a fixed pure-Python workload plus one 48-byte ``sendto``
    (to a socket of this process, drained after each tick), sized so that its median matches the loop's
    ``median_us`` (calibrated at the cadence), run ``ticks`` times at ``rate`` Hz with a sleep to the next period,
    in this process at its scheduling priority (the loop's, after the flight). Its p99 / p50 is the spread a
    constant tick shows here (cold caches after the wait, the hypervisor, interrupts), measured in the same run as
    the loop's; returns p50 / p99 (us) and their ratio."""
    import socket

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dest, payload, period = rx.getsockname(), bytes(48), 1.0 / rate

    def run(n: int, count: int) -> list[float]:
        times, t_next = [], time.perf_counter()
        for _ in range(count):
            t_next += period
            t0 = time.perf_counter()
            _constant_work(n)
            tx.sendto(payload, dest)
            times.append(time.perf_counter() - t0)
            while True:  # drain outside the timed part
                try:
                    rx.recv(64)
                except BlockingIOError:
                    break
            time.sleep(max(t_next - time.perf_counter(), 0.0))
        return times

    n = 1000
    for _ in range(6):  # scale the work to the loop's median (300 ticks each; the cost is not linear in n when cold)
        med = float(np.median(run(n, 300))) * 1e6
        n = max(1, round(n * min(max(median_us / med, 0.5), 2.0)))
    times = np.asarray(run(n, ticks)) * 1e6
    rx.close()
    tx.close()
    p50, p99 = float(np.percentile(times, 50)), float(np.percentile(times, 99))
    return {"baseline_us_p50": p50, "baseline_us_p99": p99, "baseline_p99_over_p50": p99 / p50}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[250.0, 500.0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--out", default=None)
    ap.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="SCHED_FIFO priority of the loop (0: normal scheduling); the emulator stays normal",
    )
    ap.add_argument("--pin", action="store_true", help="emulator on the last CPU, the loop on the others")
    ap.add_argument("--lockstep", action="store_true", help="emulator and loop in lockstep (a loaded machine)")
    ap.add_argument(
        "--emulator-wakeup",
        action="store_true",
        help="leave the emulator under normal scheduling (default: SCHED_BATCH, see the module docstring)",
    )
    a = ap.parse_args()
    out = Path(a.out or tempfile.mkdtemp(prefix="bench-loop-"))
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for r in a.rates:
        t0 = time.monotonic()
        rows.append(
            one(r, a.duration, out, a.rt_priority, a.pin, lockstep=a.lockstep, emulator_batch=not a.emulator_wakeup)
        )
        rows[-1]["wall_s"] = time.monotonic() - t0
        if rows[-1]["compute_us_p50"]:
            rows[-1].update(machine_baseline(r, min(rows[-1]["ticks"], 5000), rows[-1]["compute_us_p50"]))
    print(
        f"{'rate':>6} {'prio':>4} {'pin':>3} {'achieved':>9} {'compute p50/p99 us':>19} {'estimator p50/p99':>18} "
        f"{'latency p50/p99 us':>19} {'missed':>12} {'load':>5} ended"
    )
    for r in rows:
        print(
            f"{r['rate_hz']:>6.0f} {r['rt_priority']:>4} {'yes' if r['pinned'] else 'no':>3} "
            f"{r['rate_hz_achieved'] or 0:>9.1f} "
            f"{r['compute_us_p50'] or 0:>9.0f}/{r['compute_us_p99'] or 0:<9.0f} "
            f"{r['estimator_us_p50'] or 0:>8.0f}/{r['estimator_us_p99'] or 0:<9.0f} "
            f"{r['latency_us_p50'] or 0:>9.0f}/{r['latency_us_p99'] or 0:<9.0f} "
            f"{r['missed_deadlines']:>5} ({100 * (r['missed_fraction'] or 0):.2f}%) {r['load_before']:>5.1f} "
            f"{r['ended_by']}"
        )
    print(
        "\nthe machine's own spread, same run: a constant tick (fixed work + one sendto) sized to the loop's median,"
        " at the same rate and priority"
    )
    for r in rows:
        if "baseline_us_p50" in r:
            print(
                f"{r['rate_hz']:>6.0f} Hz: constant tick p50/p99 {r['baseline_us_p50']:.0f}/{r['baseline_us_p99']:.0f}"
                f" us (p99/p50 {r['baseline_p99_over_p50']:.2f}); the loop's p99/p50"
                f" {r['compute_us_p99'] / r['compute_us_p50']:.2f}"
            )
    (out / "bench_loop.json").write_text(json.dumps(rows, indent=2) + "\n")
    print(f"results: {out / 'bench_loop.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
