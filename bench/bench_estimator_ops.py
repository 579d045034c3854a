"""Cost of the Kalman filter's single operations, this filter against the frozen original (``tests/kf_reference.py``).

Both filters run side by side, alternating tick by tick, on 20 s of a 250 Hz hover stream
(``bench_estimator.record``); every fusion of a record (``_fuse``: the predictions of the blocks it touches to its
time, the gated updates, the corrections carried to the output, the bookkeeping) is timed, and the median per
record type is printed. Then, the two filters holding the same state, single operations are timed with ``timeit``
(best of 7 repeats, which filters out machine load): the prediction of each block over 2 ms, the output
prediction and ``push_command``.

Usage: ``python bench/bench_estimator_ops.py``
"""

from __future__ import annotations

import sys
import time
import timeit
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_estimator import record
from kf_reference import ReferenceKalmanEstimator

from estimators.filters.kf import KalmanEstimator
from estimators.model.vehicle import Vehicle


def at(e: object, block: int, t: float) -> None:
    """Set the time of block ``block`` of filter ``e``: a named block state in this filter, ``[t, x, P]`` in the
    frozen original."""
    core = e._core[block]  # type: ignore[attr-defined]
    if isinstance(core, list):
        core[0] = t
    else:
        core.t = t


def _block_time(e: object) -> float:
    core = e._core[0]  # type: ignore[attr-defined]
    return core[0] if isinstance(core, list) else core.t


PREDICTIONS = (
    ("predict horizontal block (8 states x 2 axes)", "at(e, 0, T0); e._advance_core(0, T0 + 0.002)"),
    ("predict heading block (2 states)", "at(e, 1, T0); e._advance_core(1, T0 + 0.002)"),
    ("predict height block (4 states)", "at(e, 2, T0); e._advance_core(2, T0 + 0.002)"),
    ("predict the output (22 means)", "e._t_out = TO; e._advance_output(TO + 0.004)"),
    ("push_command", "e._t_out = TO; e.push_command(TO, 10.0, (0.001, 0.002, 0.003))"),
)


def main() -> int:
    rate = 250.0
    ticks, start = record(rate, 20.0, "px4-typical")
    ests = (
        KalmanEstimator(Vehicle(), load_sensor=True, rate_hz=rate),
        ReferenceKalmanEstimator(Vehicle(), load_sensor=True, rate_hz=rate),
    )
    fuse_times: list[dict[str, list[float]]] = [{}, {}]
    clock = time.perf_counter
    for k, e in enumerate(ests):
        e.initialize(0.0, start)
        inner = e._fuse

        def timed(m: object, inner: object = inner, acc: dict = fuse_times[k]) -> None:
            t0 = clock()
            inner(m)
            acc.setdefault(type(m).__name__, []).append(clock() - t0)

        e._fuse = timed
    for i, (t, ms, thrust, tau) in enumerate(ticks):
        for k in (i % 2, 1 - i % 2):
            e = ests[k]
            for m in ms:
                e.push(m)
            e.estimate(t)
            e.push_command(t, thrust, tau)
    print(f"{'operation (250 Hz hover, cable sensor)':46s} {'this filter':>12s} {'original':>9s} {'speed-up':>9s}")
    for name in ("Attitude", "Imu", "PositionVelocity", "LoadAngle"):
        us = [float(np.median(ft[name])) * 1e6 for ft in fuse_times]
        print(f"{'fuse ' + name + ' (median)':46s} {us[0]:9.2f} us {us[1]:6.2f} us {us[1] / us[0]:8.2f}x")
    n = 5000

    def best(stmt: str, names: dict) -> float:
        return min(timeit.repeat(stmt, globals=names, number=n, repeat=7)) / n * 1e6

    for label, stmt in PREDICTIONS:
        us = [best(stmt, {"e": e, "at": at, "T0": _block_time(e), "TO": e._t_out}) for e in ests]
        print(f"{label:46s} {us[0]:9.2f} us {us[1]:6.2f} us {us[1] / us[0]:8.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
