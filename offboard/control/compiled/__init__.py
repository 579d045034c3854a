"""The controllers as numba kernels over the estimate vector (``estimators.kernels.EST_*``) and the reference row
(:mod:`.reference_row`): :mod:`.smc_law` (``offboard.control.smc``), :mod:`.attitude_law`
(``offboard.control.smc_attitude``), :mod:`.baseline_laws` (the cascade rows, ``swing-feedback``, ``lqr``) and
:mod:`.laws`, which picks one by its code; the laws the sweep engine (``offboard.harness.compiled``) flies, kept with
the laws' role. Importing the package drops its compiled cache when any of :data:`SOURCES` changed
(``estimators.kernels.kernel_package``)."""

from __future__ import annotations

from estimators.kernels import kernel_package

#: the scalar modules whose functions these kernels compile as they are (the switching function, the thrust
#: direction)
SHARED_SOURCES = ("estimators/model/rotations.py", "offboard/control/smc.py")
#: every file the package's compiled code depends on, and whether this import found its cache stale
SOURCES, STALE = kernel_package(__file__, SHARED_SOURCES)
