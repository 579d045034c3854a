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

Real logs (``tests/data`` and, with ``--shared DIR``, the shared folder's: ``tests/data/SOURCES.md``): scan and
replay timed against the log's own vehicle-time span and against its airborne span (aim: >= 30x the log's
duration), in wall time and in this process's CPU time (what a quiet machine's wall time would be).

Usage: ``python bench/bench_replay.py [--seconds S] [--repeat N] [--real-only] [--shared DIR]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from pymavlink import mavutil
from tlog_fixtures import LogSpec, flight_log, offboard_log

from offboard.logs import replay as rp
from offboard.logs.tlog import TlogReader


def _median_time(fn: Callable[[], object], repeat: int) -> float:
    return _median_times(fn, repeat)[0]


def _median_times(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """(wall, CPU) seconds of ``fn``, each the median over ``repeat`` runs. Why the CPU time too: on a machine
    shared with other jobs the wall time measures the queue for a core (at load 19 on 2 cores, four to five times
    the CPU time); this process's CPU time is what a quiet machine's wall time would be (a little above it:
    the other jobs still share the caches)."""
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


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
    print(
        f"\n{name}: {duration:.0f} s of log, {len(data) / 1e6:.2f} MB, {n_packets} packets "
        f"({n_packets / duration:.0f}/s), {ticks} ticks ({res.metrics['estimation']['tick_source']})"
    )
    rows = [
        ("read (slung tlog reader)", t_read),
        ("read (pymavlink mavutil, baseline)", t_base),
        ("scan: read + inventory + decode", t_scan),
        ("replay: estimator / controller", t_replay),
        ("total (scan + replay)", t_scan + t_replay),
    ]
    for label, t in rows:
        print(f"  {label:<36} {t * 1e3:9.1f} ms  {duration / t:8.1f}x real time")
    print(
        f"  reader vs pymavlink: {t_base / t_read:.2f}x; per packet {t_read / n_packets * 1e6:.1f} us; "
        f"replay per tick {t_replay / max(ticks, 1) * 1e6:.0f} us"
    )
    return {"read": t_read, "baseline": t_base, "scan": t_scan, "replay": t_replay, "packets": n_packets}


def _real_logs(shared: Path | None) -> list[Path]:
    """The real logs to time: tests/data's and, when present, the shared folder's (tests/data/SOURCES.md)."""
    data = Path(__file__).resolve().parent.parent / "tests" / "data"
    logs = sorted(p for p in data.iterdir() if p.suffix in (".tlog", ".ulg", ".bin"))
    if shared is not None and shared.is_dir():
        logs += sorted(p for p in shared.iterdir() if p.suffix in (".tlog", ".ulg", ".bin"))
    return logs


def bench_real(path: Path, repeat: int, vehicle: str | None) -> dict[str, float] | None:
    """Time scan + replay of a real log (the work of ``slung replay`` before it writes files) against the log's own
    duration: the autopilot's vehicle-time span, and the airborne span the estimator ran over."""
    from estimators.model.vehicle import load_vehicle
    from offboard.logs.log_formats import log_format_of, scan_dataflash, scan_ulog

    fmt = log_format_of(path)

    def scan() -> rp.Scan:
        if fmt == "ulog":
            return scan_ulog(path)
        if fmt == "dataflash":
            return scan_dataflash(path)
        return rp.scan(TlogReader.from_path(path))

    t_scan, c_scan = _median_times(lambda: rp.inventory(scan()), repeat)
    sc = scan()
    inv = rp.inventory(sc)
    ap = next((s for s in inv["systems"] if s["sysid"] == inv["autopilot_sysid"]), None)
    span = (ap or {}).get("vehicle_time_span_s") or 0.0
    ok, reasons = rp.replayable(inv)
    print(f"\n{path.name} ({fmt}, {path.stat().st_size / 1e6:.2f} MB): vehicle time span {span:.1f} s")
    print(f"  {'':<36} {'wall':>9}     {'CPU':>9}     wall and CPU vs the log's span")
    print(
        f"  {'scan: read + inventory + decode':<36} {t_scan * 1e3:9.1f} ms  {c_scan * 1e3:9.1f} ms  "
        f"{span / t_scan:7.1f}x {span / c_scan:7.1f}x"
    )
    if not ok:
        print(f"  not replayable: {'; '.join(reasons)}")
        return {"scan": t_scan, "scan_cpu": c_scan, "span": span}
    cfg = rp.ReplayConfig(vehicle=load_vehicle(vehicle))
    rp.replay(sc, inv, cfg)  # warm-up
    t_replay, c_replay = _median_times(lambda: rp.replay(sc, inv, cfg), repeat)
    res = rp.replay(sc, inv, cfg)
    est = res.metrics["estimation"]
    flown = sum(s["duration_s"] for s in inv["airborne_segments"])
    total, total_cpu = t_scan + t_replay, c_scan + c_replay
    print(
        f"  {'replay: estimator (+ checks)':<36} {t_replay * 1e3:9.1f} ms  {c_replay * 1e3:9.1f} ms  "
        f"{est['ticks']} ticks"
    )
    print(
        f"  {'total (scan + replay)':<36} {total * 1e3:9.1f} ms  {total_cpu * 1e3:9.1f} ms  "
        f"{span / total:7.1f}x {span / total_cpu:7.1f}x the log's span"
    )
    print(f"  {'':<62} {flown / total:7.1f}x {flown / total_cpu:7.1f}x its airborne span ({flown:.1f} s)")
    return {
        "scan": t_scan,
        "replay": t_replay,
        "scan_cpu": c_scan,
        "replay_cpu": c_replay,
        "span": span,
        "flown": flown,
    }


def main(argv: list[str] | None = None) -> None:
    """Run both benchmarks and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="log duration, s (default 20)")
    ap.add_argument("--repeat", type=int, default=3, help="repeats per stage (median reported, default 3)")
    ap.add_argument(
        "--real-only", action="store_true", help="time only the real logs (tests/data and --shared), not generated ones"
    )
    ap.add_argument("--shared", type=Path, default=None, help="folder of further real logs (shared/logs)")
    args = ap.parse_args(argv)
    vehicles = {"px4-sitl-sih-hover.ulg": "px4-sih", "arducopter-sitl-dronekit-la-log171.bin": "ardupilot-sitl-quad"}
    load = os.getloadavg()[0]
    print(f"real logs (scan + replay against the log's own duration; aim >= 30x; load {load:.1f}):", flush=True)
    for path in _real_logs(args.shared):
        bench_real(path, args.repeat, vehicles.get(path.name))
    if args.real_only:
        return
    print("generating logs ...", flush=True)
    est_log = flight_log(LogSpec(seconds=args.seconds))
    off_log, _ = offboard_log(seconds=args.seconds)
    bench("estimation", est_log, args.seconds, rp.ReplayConfig(rate_hz=250.0), args.repeat)
    bench("offboard", off_log, args.seconds, rp.ReplayConfig(reference=rp.ReferenceSpec("hover")), args.repeat)


if __name__ == "__main__":
    main()
