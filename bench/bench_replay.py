"""Speed of ``slung replay`` on 250 Hz logs, stage by stage, as a multiple of the log's duration ("x real time").

Logs are generated here (``tests/tlog_fixtures.py``: the plant streaming ATTITUDE and HIGHRES_IMU at 250 Hz,
LOCAL_POSITION_NED and the cable-angle sensor at 50 Hz, HEARTBEAT at 1 Hz):

- ``estimation``: a log with no offboard flight: the estimator ticks on a 250 Hz grid;
- ``offboard``: a flight flown at 250 Hz by the loop's building blocks: per tick estimator + controller + mapping,
  recomputed setpoints compared with the logged ones.

Stages, each the median wall time over ``--repeat`` runs: ``read`` (the robust reader alone, with pymavlink's own
``mavutil`` tlog reader measured in the same run as the baseline), ``scan`` (read + inventory + telemetry
decoding), ``replay`` (estimator / controller pass), ``total`` (scan + replay, what ``slung replay`` does before
writing files). Aim (issue 6): total >= 50x real time.

Usage: ``python bench/bench_replay.py [--seconds S] [--repeat N]``
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from pymavlink import mavutil
from tlog_fixtures import LogSpec, flight_log, offboard_log

from offboard import replay as rp
from offboard.tlog import TlogReader


def _median_time(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _pymavlink_read(path: str) -> int:
    conn = mavutil.mavlink_connection(path)
    n = 0
    while conn.recv_match() is not None:
        n += 1
    return n


def bench(name: str, data: bytes, duration: float, config: rp.ReplayConfig, repeat: int) -> dict[str, float]:
    """Time the stages on one log; returns seconds per stage and the packet count."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}.tlog"
        path.write_bytes(data)
        n_packets = sum(1 for _ in TlogReader(data))
        t_read = _median_time(lambda: sum(1 for _ in TlogReader(data)), repeat)
        t_base = _median_time(lambda: _pymavlink_read(str(path)), repeat)
    t_scan = _median_time(lambda: rp.inventory(rp.scan(TlogReader(data))), repeat)
    sc = rp.scan(TlogReader(data))
    inv = rp.inventory(sc)
    rp.replay(sc, inv, config)  # warm-up: imports, discretization caches
    t_replay = _median_time(lambda: rp.replay(sc, inv, config), repeat)
    res = rp.replay(sc, inv, config)
    ticks = res.metrics["estimation"]["ticks"]
    print(f"\n{name}: {duration:.0f} s of log, {len(data) / 1e6:.2f} MB, {n_packets} packets "
          f"({n_packets / duration:.0f}/s), {ticks} ticks ({res.metrics['estimation']['tick_source']})")
    rows = [("read (slung tlog reader)", t_read), ("read (pymavlink mavutil, baseline)", t_base),
            ("scan: read + inventory + decode", t_scan), ("replay: estimator / controller", t_replay),
            ("total (scan + replay)", t_scan + t_replay)]
    for label, t in rows:
        print(f"  {label:<36} {t * 1e3:9.1f} ms  {duration / t:8.1f}x real time")
    print(f"  reader vs pymavlink: {t_base / t_read:.2f}x; per packet {t_read / n_packets * 1e6:.1f} us; "
          f"replay per tick {t_replay / max(ticks, 1) * 1e6:.0f} us")
    return {"read": t_read, "baseline": t_base, "scan": t_scan, "replay": t_replay, "packets": n_packets}


def main(argv: list[str] | None = None) -> None:
    """Run both benchmarks and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="log duration, s (default 20)")
    ap.add_argument("--repeat", type=int, default=3, help="repeats per stage (median reported, default 3)")
    args = ap.parse_args(argv)
    print("generating logs ...", flush=True)
    est_log = flight_log(LogSpec(seconds=args.seconds))
    off_log, _ = offboard_log(seconds=args.seconds)
    bench("estimation", est_log, args.seconds, rp.ReplayConfig(rate_hz=250.0), args.repeat)
    bench("offboard", off_log, args.seconds, rp.ReplayConfig(reference=rp.ReferenceSpec("hover")), args.repeat)


if __name__ == "__main__":
    main()
