"""The compiled sweep engine (``engine = "compiled"``): each run of a sweep flown by machine code (numba), the
same equations, in the same order, as the scalar path (``offboard.harness.sim.run``), one run after another.

It composes kernels that live with their roles, and mirrors none:

- ``estimators.kernels``: the JIT decorators, the estimate's layout, the record codes and Python's ``min``, ``max``,
  ``math.hypot`` for kernels mirroring scalar Python;
- ``estimators.filters.compiled``: the measured-input Kalman filter (``estimators.filters.measured_kf``);
- ``offboard.control.compiled``: the controllers (``smc``, ``smc-attitude``, the cascade rows, ``swing-feedback``,
  ``lqr``) and the reference row's layout;
- ``sim_bridge.plant.compiled``: the plant, its drag, the cable tension, the sensors' values, the gust, the mixer;
- ``sim_bridge.inner.compiled``: PX4's attitude P, rate PID, allocator and motors, which ``smc-attitude`` flies
  through.

Its own modules:

- :mod:`.layout`: the engine's compile-once cache (which depends on all of the above);
- :mod:`.schedule`: a run's sensor records and the filter's events, from the run's generator;
- :mod:`.inputs`: a run's reference rows, record arrays, and the law's and actuators' constants;
- :mod:`.engine`: one run's loop, and the sweep's rows for a chunk of runs.
"""

from offboard.harness.compiled import layout as _layout  # noqa: F401  (its import judges the cache, first)
