"""The compiled sweep engine (``engine = "compiled"``): each run of a sweep flown by machine code (numba), the
same equations, in the same order, as the scalar path (``offboard.harness.sim.run``), one run after another.

- :mod:`.layout`: the reference row's layout and the package's compile-once cache; the JIT decorators, the estimate's
  layout and Python's ``min``, ``max``, ``math.hypot`` for kernels mirroring scalar Python are ``estimators.kernels``'s;
- :mod:`.plant`: the plant, its drag, the cable tension, the sensors' values, the gust, the mixer;
- the measured-input Kalman filter (``estimators.filters.measured_kf``): its kernels are the filter's own,
  ``estimators.filters.compiled``;
- :mod:`.laws`: the controllers (``smc``, the cascade rows, ``swing-feedback``, ``lqr``);
- :mod:`.attitude_law`: the attitude-level law (``smc-attitude``);
- :mod:`.px4_loops`: PX4's attitude P, rate PID, allocator and motors, which ``smc-attitude`` flies through;
- :mod:`.schedule`: a run's sensor records and the filter's events, from the run's generator;
- :mod:`.inputs`: a run's reference rows, record arrays, and the law's and actuators' constants;
- :mod:`.engine`: one run's loop, and the sweep's rows for a chunk of runs.
"""

from offboard.harness.compiled import layout as _layout  # noqa: F401  (its import judges the cache, first)
