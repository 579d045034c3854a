"""Cost per 250 Hz control tick of the two Kalman filters on a PX4-like hover stream (ATTITUDE 100 Hz, HIGHRES_IMU
50 Hz, LOCAL_POSITION_NED 30 Hz), with stamps on the 1 ms grid and with microsecond jitter (ArduPilot's
HIGHRES_IMU: thousands of distinct step lengths). Best of ``--repeat`` runs per case (median, p99, mean).

    python bench/bench_filter_stamps.py [--repeat N] [--seconds S]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_measured_kf import V, _hover_stream, _run

from estimators.filters.factory import make_estimator


def _cost(kind: str, recs: list, ticks: list[float], load: bool, repeat: int) -> tuple[float, float, float]:
    v = V if load else V.with_changes(mass_load=0.0)
    best = []
    for _ in range(repeat):
        costs = _run(make_estimator(kind, v, load_sensor=False, rate_hz=250.0), recs, ticks, thrust=7.0)
        best.append((float(np.median(costs)), float(np.percentile(costs, 99)), float(np.mean(costs))))
    return min(best)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=6.0)
    args = ap.parse_args()
    grid, ticks = _hover_stream(2, args.seconds, jitter_us=False)
    jitter, _ = _hover_stream(2, args.seconds, jitter_us=True)
    print(f"{len(grid) / len(ticks):.2f} records per tick, {len(ticks)} ticks at 250 Hz, best of {args.repeat}")
    for kind in ("kf", "kf-torque"):
        for load in (True, False):
            for name, recs in (("grid", grid), ("us-jitter", jitter)):
                med, p99, mean = _cost(kind, recs, ticks, load, args.repeat)
                label = f"{kind:9s} {'load' if load else 'no load':7s} {name:9s}"
                print(f"{label} median {med * 1e6:6.1f} us  p99 {p99 * 1e6:7.1f} us  mean {mean * 1e6:6.1f} us")


if __name__ == "__main__":
    main()
