"""The sweep engine's reference row and its compile-once cache (checked when the package is imported, before any of
its kernels runs). The decorators, the estimate vector's layout, the record codes and the numeric helpers every
kernel shares are ``estimators.kernels``'s; the filter's kernels are ``estimators.filters.compiled``'s.

The reference row (``REF_SIZE`` floats): ``offboard.control.reference.FlatSample`` flattened, orders 0..6 of
``F_x``, ``F_y``, ``z`` and ``psi``.
"""

from __future__ import annotations

from pathlib import Path

from estimators.filters import compiled as filter_kernels
from estimators.kernels import ROOT, drop_stale_cache

_PACKAGE = Path(__file__).resolve().parent
#: the scalar path's modules whose functions kernels compile as they are (one source for both paths: the quaternion
#: helpers, the cable's projection; the filter's own in ``estimators.filters.compiled.SHARED_SOURCES``); numba
#: caches an inlined function inside its caller's file, so a change to one of these must drop the package's cache
#: as a change to the package does
SHARED_SOURCES = (
    *filter_kernels.SHARED_SOURCES,
    "offboard/control/smc.py",
    "sim_bridge/inner/px4_inner.py",
    "sim_bridge/plant/dynamics.py",
)


def _engine_sources() -> list[Path]:
    """Every file the engine's compiled code depends on: its modules, the filter's kernels and their sources, and
    :data:`SHARED_SOURCES`."""
    return [*sorted(_PACKAGE.glob("*.py")), *filter_kernels.SOURCES, *(ROOT / s for s in SHARED_SOURCES)]


def _drop_stale_cache() -> bool:
    """The package's compiled cache thrown away when any of :func:`_engine_sources` changed
    (``estimators.kernels.drop_stale_cache``); True when it was."""
    return drop_stale_cache(_PACKAGE, _engine_sources())


_drop_stale_cache()

# ---- the reference (FlatSample) -----------------------------------------------------------------------------------
REF_FX = 0  # orders 0..6 (7 floats)
REF_FY = 7
REF_Z = 14
REF_PSI = 21
REF_SIZE = 28
