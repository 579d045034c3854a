"""Why ``kf-torque``'s heading and height updates are unrolled over plain floats (``estimators/filters/kf_update.py``):
each against the readable :meth:`~estimators.filters.linear_block.LinearBlock.update_states` on the same block as
numpy arrays, per call (min of 5 x 50 000; the unrolled ones also carry the correction to the output).

Usage: ``python bench/bench_kf_unrolled.py``
"""

from __future__ import annotations

import timeit

import numpy as np

from estimators.filters.kf import KalmanEstimator
from estimators.filters.linear_block import LinearBlock
from estimators.model.flatness import flat_constants, truth_control_state
from estimators.model.vehicle import Vehicle
from sim_bridge.plant import dynamics

HEADING_P = [4e-4, 0.0, 0.0, 2.5e-3]  # row-major 2 x 2
HEIGHT_P = [2.5e-3, 0.0, 0.0, 0.0, 1e-2, 0.0, 0.0, 0.09, 0.0, 0.01]  # upper triangle of 4 x 4


def main() -> None:
    v = Vehicle()
    e = KalmanEstimator(v, load_sensor=True, rate_hz=250.0)
    e.initialize(0.0, truth_control_state(dynamics.make_state(), flat_constants(v)))
    core = e._core  # type: ignore[attr-defined]
    yx, yp = np.zeros((1, 2)), np.zeros((2, 2))
    zx, zp = np.zeros((1, 4)), np.zeros((4, 4))

    def heading() -> None:
        core[1].p, core[1].x = list(HEADING_P), [0.0, 0.0]
        e._update_heading(0.001, 0.002)  # type: ignore[attr-defined]

    def height() -> None:
        core[2].p, core[2].x = list(HEIGHT_P), [0.0, 0.0, 0.0, 0.0]
        e._update_height_pv(0.001, 0.002)  # type: ignore[attr-defined]

    def heading_arrays() -> None:
        yp[:] = np.diag([4e-4, 2.5e-3])
        yx[:] = 0.0
        LinearBlock.update_states(yx, yp, (0, 1), (0.001, 0.002), (1e-4, 1e-4), 1e9)

    def height_arrays() -> None:
        zp[:] = np.diag([2.5e-3, 1e-2, 0.09, 0.01])
        zx[:] = 0.0
        LinearBlock.update_states(zx, zp, (0, 1), (0.001, 0.002), (9e-4, 9e-4), 1e9)

    n = 50_000
    for name, f in (
        ("heading, unrolled floats", heading),
        ("heading, LinearBlock.update_states", heading_arrays),
        ("height, unrolled floats", height),
        ("height, LinearBlock.update_states", height_arrays),
    ):
        print(f"{name:40s} {min(timeit.repeat(f, number=n, repeat=5)) / n * 1e6:6.2f} us")


if __name__ == "__main__":
    main()
