"""The compiled sweep engine (``engine = "compiled"``): each run of a sweep flown by machine code (numba), the
same equations, in the same order, as the scalar path (``offboard.harness.sim.run``) and the numpy batched path
(``offboard.harness.batched``), one run after another.

- :mod:`.layout`: the shared vector layouts (the estimate, the reference) and the JIT decorator every kernel uses;
- :mod:`.plant`: the plant, its drag, the cable tension, the sensors' values, the gust, the mixer;
- :mod:`.kf`: the measured-input Kalman filter (``estimators.filters.measured_kf``);
- :mod:`.laws`: the controllers (``smc``, the cascade rows, ``swing-feedback``, ``lqr``);
- :mod:`.schedule`: a run's sensor records and the filter's events, from the run's generator;
- :mod:`.engine`: one run's loop, and the sweep's rows for a chunk of runs.
"""
