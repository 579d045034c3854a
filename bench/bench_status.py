"""Cost of the live status display to the real-time loop: ``bench_loop.one`` flights of the ``hover`` scenario at
250 Hz against ``slung emulate --realtime``, alternately without the display (``quiet``) and with it drawing its
status line four times a second as on a terminal (stderr replaced by a stream that says it is a terminal and
discards what it is given), ``--pairs`` times. Prints compute / latency p50 / p99 and missed deadlines of each
flight, the CPU time of the display's thread (from /proc, clock-tick resolution), then the median of each over
the pairs and the ratio with / without, with the load average.

    python bench/bench_status.py [--pairs 3] [--duration 20] [--rate 250]

``--same-run``: one flight instead, the display switched on and off in alternate ``--window`` seconds (1 s) of the
same run, so that both halves see the same machine load; the ticks are split by the window they started in
(``t_local`` of ``timeseries_live.slts``) and their compute time and latency compared (median, p99), beside the
time each status line took to draw (the display holds the interpreter that long: the most it can delay a tick).

    python bench/bench_status.py --same-run [--duration 30] [--window 1] [--rate 250]
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_loop import one

from offboard.logs.timeseries_file import read_table

KEYS = ("compute_us_p50", "compute_us_p99", "latency_us_p50", "latency_us_p99", "missed_fraction")


class _ThreadCpu:
    """CPU time (user + system, s) of the thread named ``name`` while it lives, from /proc/self/task/TID/stat
    (Linux; clock-tick resolution, usually 10 ms), sampled every ``every_s`` by a thread of this benchmark."""

    def __init__(self, name: str = "slung-status", every_s: float = 0.2) -> None:
        self.name, self.every_s, self.cpu_s = name, every_s, 0.0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        tick = os.sysconf("SC_CLK_TCK")
        while not self._stop.wait(self.every_s):
            for th in threading.enumerate():
                if th.name == self.name and th.native_id is not None:
                    try:
                        with open(f"/proc/self/task/{th.native_id}/stat", encoding="ascii") as fh:
                            f = fh.read().rsplit(")", 1)[1].split()
                        self.cpu_s = max(self.cpu_s, (int(f[11]) + int(f[12])) / tick)
                    except (OSError, IndexError, ValueError):
                        pass

    def stop(self) -> float:
        self._stop.set()
        self._t.join()
        return self.cpu_s


class _FakeTerminal(io.TextIOBase):
    """A stderr that reports being a terminal and drops the text (the display's cost is in formatting and writing
    from its thread; where the bytes go is the terminal's business)."""

    def isatty(self) -> bool:
        return True

    def write(self, s: str) -> int:
        return len(s)


def _display_in_alternate_windows(window_s: float) -> tuple[list[float], object]:
    """Make every FlightStatus built from now on work only in even ``window_s`` windows of monotonic time (it sleeps
    through the odd ones) and time each status line it draws; returns (draw durations in s, undo)."""
    from offboard.flight import status as st

    draws: list[float] = []
    real_run, real_line = st.FlightStatus._run, st.FlightStatus._status_line

    def run(self: st.FlightStatus) -> None:
        real_wait = self._stop.wait

        def wait(timeout: float | None = None) -> bool:  # the display's pause, stretched over the off windows
            while True:
                if real_wait(timeout):
                    return True
                if int(time.monotonic() // window_s) % 2 == 0:
                    return False

        self._stop.wait = wait  # type: ignore[method-assign]
        real_run(self)

    def line(self: st.FlightStatus) -> None:
        t0 = time.perf_counter()
        real_line(self)
        draws.append(time.perf_counter() - t0)

    st.FlightStatus._run, st.FlightStatus._status_line = run, line  # type: ignore[method-assign]

    def undo() -> None:
        st.FlightStatus._run, st.FlightStatus._status_line = real_run, real_line  # type: ignore[method-assign]

    return draws, undo


def same_run(rate: float, duration: float, window_s: float) -> int:
    """One flight, the display on in even windows and off in odd ones; prints the two halves' tick timings."""
    draws, undo = _display_in_alternate_windows(window_s)
    with tempfile.TemporaryDirectory() as tmp:
        old, old_out = sys.stderr, sys.stdout
        sys.stderr, sys.stdout = _FakeTerminal(), _FakeTerminal()
        try:
            r = one(rate, duration, Path(tmp), status=True)
        finally:
            sys.stderr, sys.stdout = old, old_out
            undo()
        table = read_table(Path(tmp) / f"loop-{rate:g}-p0-status" / "timeseries_live.slts")
        header, data = list(table.columns), table.data
    col = {n: data[:, i] for i, n in enumerate(header)}
    on = (np.floor(col["t_local"] / window_s) % 2) == 0
    print(
        f"one {duration:g} s hover at {rate:g} Hz against slung emulate --realtime, display on in alternate"
        f" {window_s:g} s windows; ended by {r['ended_by']}; load {r['load_before']:.1f} -> {r['load_after']:.1f}"
    )
    for name, unit in (("compute_s", "compute"), ("latency_s", "latency")):
        for label, sel in (("without", ~on), ("with   ", on)):
            v = col[name][sel]
            v = v[np.isfinite(v)] * 1e6
            print(
                f"  {unit:8s} {label} display: {len(v):5d} ticks, median {np.median(v):7.0f} us, "
                f"p99 {np.percentile(v, 99):7.0f} us"
            )
    d = np.asarray(draws) * 1e6
    if len(d):
        print(f"  status lines drawn: {len(d)}, each median {np.median(d):.0f} us, p99 {np.percentile(d, 99):.0f} us")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=250.0)
    ap.add_argument("--same-run", action="store_true", help="one flight, the display on in alternate windows")
    ap.add_argument("--window", type=float, default=1.0, help="length of each on / off window of --same-run, s")
    a = ap.parse_args()
    if a.same_run:
        return same_run(a.rate, a.duration, a.window)
    rows: dict[bool, list[dict]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.pairs):
            for status in (False, True) if k % 2 == 0 else (True, False):
                old, old_out = sys.stderr, sys.stdout
                if status:
                    sys.stderr = _FakeTerminal()
                    sys.stdout = _FakeTerminal()  # the flight's summary table
                cpu = _ThreadCpu()
                try:
                    r = one(a.rate, a.duration, Path(tmp), status=status)
                finally:
                    sys.stderr, sys.stdout = old, old_out
                    r_cpu = cpu.stop()
                if status:
                    print(f"status display thread: {r_cpu:.3f} s CPU over a {a.duration:g} s flight", flush=True)
                rows[status].append(r)
                print(
                    f"{'status' if status else 'quiet '} "
                    + " ".join(f"{key} {r[key]:.4g}" for key in KEYS)
                    + f" load {r['load_before']:.1f}",
                    flush=True,
                )
    print(f"median over {a.pairs} pairs (load now {os.getloadavg()[0]:.1f}):")
    for key in KEYS:
        q = statistics.median(r[key] for r in rows[False])
        s = statistics.median(r[key] for r in rows[True])
        print(f"  {key:16s} quiet {q:10.4g}  status {s:10.4g}  ratio {s / q if q else float('nan'):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
