"""The measured-input Kalman filter (``estimators.filters.measured_kf``) as numba kernels over flat arrays: the
filter the sweep engine (``offboard.harness.compiled``) runs in every run, kept with the filter's role.

- :mod:`.kf`: the entry points (initialize, push a command, fuse a record, the estimate);
- :mod:`.kf_layout`: the arrays' layouts and constants;
- :mod:`.kf_predict`: the blocks' models and prediction;
- :mod:`.kf_update`: the gated updates and the channels' adapted noise.

Importing the package drops its compiled cache when any of :data:`SOURCES` changed (``estimators.kernels``).
"""

from __future__ import annotations

from estimators.kernels import kernel_package

#: the scalar modules whose functions these kernels compile as they are (one source for the scalar filter and the
#: kernels: the block models, the cable's pull, the Euler rates, the world tilt)
SHARED_SOURCES = (
    "estimators/filters/small_kf.py",
    "estimators/model/cable.py",
    "estimators/model/flatness.py",
    "estimators/model/frames.py",
    "estimators/model/rotations.py",
)
#: every file the package's compiled code depends on (its modules and :data:`SHARED_SOURCES`), and whether this import
#: found its compiled cache stale (the kernels then compile on their first call)
SOURCES, STALE = kernel_package(__file__, SHARED_SOURCES)
