"""PX4's attitude P, rate PID, allocator and motors (``sim_bridge.inner.px4_inner``) as numba kernels over flat
arrays (:mod:`.px4_loops`): the inner loops the sweep engine flies the attitude-level law through, kept with the
inner loops' role. Importing the package drops its compiled cache when any of :data:`SOURCES` changed
(``estimators.kernels.kernel_package``)."""

from __future__ import annotations

from estimators.kernels import kernel_package
from sim_bridge.plant import compiled as plant_kernels

#: the scalar modules whose functions these kernels compile as they are (PX4's quaternion helpers; the plant's
#: kernels, the body rates, come in through ``plant_kernels.SOURCES``)
SHARED_SOURCES = ("estimators/model/frames.py", "estimators/model/rotations.py", "sim_bridge/inner/px4_inner.py")
#: every file the package's compiled code depends on, and whether this import found its cache stale
SOURCES, STALE = kernel_package(__file__, SHARED_SOURCES, plant_kernels.SOURCES)
