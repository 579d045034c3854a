"""The sweep engine's compile-once cache, checked when the package is imported, before any of its kernels runs. The
engine composes kernels that live with their roles: the decorators, the estimate's layout and the record codes in
``estimators.kernels``, the filter in ``estimators.filters.compiled``, the laws (and the reference row) in
``offboard.control.compiled``, the plant in ``sim_bridge.plant.compiled``, PX4's inner loops in
``sim_bridge.inner.compiled``; each of those packages judges its own cache, and the engine's depends on them all.
"""

from __future__ import annotations

from estimators.filters import compiled as filter_kernels
from estimators.kernels import kernel_package
from offboard.control import compiled as law_kernels
from sim_bridge.inner import compiled as inner_kernels
from sim_bridge.plant import compiled as plant_kernels

#: the kernel packages the engine compiles in
KERNEL_PACKAGES = (filter_kernels, law_kernels, plant_kernels, inner_kernels)
#: the scalar modules whose functions some kernel compiles as it is (one source for both paths), every kernel
#: package's :data:`SHARED_SOURCES` together
SHARED_SOURCES = tuple(sorted({s for k in KERNEL_PACKAGES for s in k.SHARED_SOURCES}))


#: every file the engine's compiled code depends on (its modules and each kernel package's sources), and whether
#: this import found its compiled cache stale (the engine's kernels then compile on their first call)
SOURCES, STALE = kernel_package(__file__, (), *(k.SOURCES for k in KERNEL_PACKAGES))
