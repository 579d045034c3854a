"""Where the live loop's tick spends its time: one ``bench_loop`` flight (250 Hz, lockstep by default) with the tick's
parts timed as they run (``time.perf_counter`` around each call; the loop's code is observed, not replaced).

Parts: the whole tick (``ControlTick.__call__``: estimate, reference, controller, mapping, command to the filter), of
which the filter's estimate (``estimate_ahead``), each record it fuses and its output state, the controller step and
the setpoint mapping; outside the tick the setpoint's encoding and ``sendto`` (``FlightLoop._send``) and the
watchdogs. Medians, p90 and p99 in microseconds; the loop's own compute figure (tick start to setpoint written)
beside them. The timers add about a microsecond per call. Then, as a baseline measured in the same run, what one
``sendto`` of a setpoint-sized datagram to a receiver blocked in ``recv`` costs alone on this machine (at the
loop's rate and priority): the kernel's wake-up of the receiver, which no Python in the loop can remove.

    python bench/bench_loop_parts.py [--rate 250] [--duration 20] [--rt-priority N] [--realtime]
"""

from __future__ import annotations

import argparse
import functools
import os
import socket
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_loop import one

from estimators.filters.measured_predict import MeasuredPrediction
from estimators.filters.measured_update import MeasuredUpdates
from offboard.control.controllers import sliding_mode
from offboard.control.tick import ControlTick
from offboard.flight import loop
from offboard.flight.command_mapping import CommandMapper


def _timed(owner: Any, name: str, label: str, times: dict[str, list[float]]) -> Callable[[], None]:
    """Time every call of ``owner.name`` into ``times[label]`` (s); returns the function that puts it back."""
    inner = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
    acc = times.setdefault(label, [])
    clock = time.perf_counter

    @functools.wraps(inner)
    def timed(*args: Any, **kw: Any) -> Any:
        t0 = clock()
        try:
            return inner(*args, **kw)
        finally:
            acc.append(clock() - t0)

    setattr(owner, name, timed)
    return lambda: setattr(owner, name, inner)


def sendto_alone(rate_hz: float, n: int = 2000) -> np.ndarray:
    """Seconds per ``sendto`` of 51 bytes (a SET_ATTITUDE_TARGET) to a child process blocked in ``recv`` on
    127.0.0.1, one every period at ``rate_hz``."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    pid = os.fork()
    if pid == 0:  # the receiver: blocked in recv until told to stop
        while rx.recv(64) != b"q":
            pass
        os._exit(0)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    addr, buf, out = rx.getsockname(), b"x" * 51, np.empty(n)
    clock = time.perf_counter
    try:
        for i in range(n):
            t0 = clock()
            tx.sendto(buf, addr)
            out[i] = clock() - t0
            time.sleep(1.0 / rate_hz)
    finally:
        tx.sendto(b"q", addr)
        os.waitpid(pid, 0)
        tx.close()
        rx.close()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=250.0)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--rt-priority", type=int, default=0, help="SCHED_FIFO priority of the loop (0: normal)")
    ap.add_argument("--realtime", action="store_true", help="the emulator in real time instead of lockstep")
    a = ap.parse_args()
    times: dict[str, list[float]] = {}
    parts = [
        (ControlTick, "__call__", "tick"),
        (loop, "estimate_ahead", "  filter estimate"),
        (MeasuredUpdates, "_fuse", "    one record fused"),
        (MeasuredPrediction, "_control_state", "    output state"),
        (sliding_mode.PureStepController, "step", "  controller step"),
        (CommandMapper, "map", "  setpoint mapping"),
        (loop.FlightLoop, "_send", "setpoint encoding + sendto"),
        (loop.FlightLoop, "_watchdogs", "watchdogs"),
    ]
    restore = [_timed(owner, name, label, times) for owner, name, label in parts]
    try:
        out = Path(tempfile.mkdtemp(prefix="bench-loop-parts-"))
        r = one(a.rate, a.duration, out, a.rt_priority, lockstep=not a.realtime)
    finally:
        for undo in restore:
            undo()
    print(
        f"{a.rate:g} Hz, {'real time' if a.realtime else 'lockstep'}, priority {a.rt_priority}, load "
        f"{r['load_before']:.1f}, {r['ticks']} ticks, ended {r['ended_by']}: compute p50/p99 "
        f"{r['compute_us_p50'] or 0:.0f}/{r['compute_us_p99'] or 0:.0f} us"
    )
    print(f"{'part':<30} {'calls':>7} {'p50 us':>8} {'p90 us':>8} {'p99 us':>8}")
    for label, v in times.items():
        if v:
            us = np.array(v) * 1e6
            print(
                f"{label:<30} {len(v):>7} {np.median(us):>8.1f} {np.percentile(us, 90):>8.1f} "
                f"{np.percentile(us, 99):>8.1f}"
            )
    if a.rt_priority > 0:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.rt_priority))
    try:
        us = sendto_alone(a.rate) * 1e6
    finally:
        if a.rt_priority > 0:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    print(
        f"baseline, same run: sendto alone to a blocked receiver {len(us)} x p50/p99 {np.median(us):.1f}/"
        f"{np.percentile(us, 99):.1f} us"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
