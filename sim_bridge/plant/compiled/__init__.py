"""The plant as numba kernels over flat arrays (:mod:`.plant`: the plant of ``sim_bridge.plant.dynamics``, its drag,
the cable tension, the sensors' values, the sweep's gust, the four-motor mixer): the vehicle the sweep engine
(``offboard.harness.compiled``) flies, kept with the plant's role. Importing the package drops its compiled cache when
any of :data:`SOURCES` changed (``estimators.kernels.kernel_package``)."""

from __future__ import annotations

from estimators.kernels import kernel_package

#: the scalar modules whose functions these kernels compile as they are (the cable's projection, the thrust
#: direction, the body rates, the planar swing angles)
SHARED_SOURCES = ("estimators/model/cable.py", "estimators/model/rotations.py", "sim_bridge/plant/dynamics.py")
#: every file the package's compiled code depends on, and whether this import found its cache stale
SOURCES, STALE = kernel_package(__file__, SHARED_SOURCES)
