"""What every compiled kernel shares: the JIT decorator and the layouts of the vectors passed between kernels.

Kernels are numba ``njit`` functions with ``error_model="numpy"`` (a division by zero gives inf or NaN, as numpy
does, instead of raising: the kernels run inside a simulated run, which reports a non-finite state as diverged)
and ``cache=True`` (compiled once per machine, then loaded from ``__pycache__``). No ``fastmath``: the kernels
keep IEEE arithmetic and the scalar path's order of operations, so that a run equals the scalar path's to the
last bits or nearly (``tests/test_compiled_engine.py``).

The estimate vector (``EST_SIZE`` floats): ``estimators.model.control_state.ControlState`` flattened, SI units,
world NWU frame as in the scalar path: the flat chains ``F_x``, ``F_y`` (orders 0..5) then the named scalars.

The reference row (``REF_SIZE`` floats): ``offboard.control.reference.FlatSample`` flattened, orders 0..6 of
``F_x``, ``F_y``, ``z`` and ``psi``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numba

_PACKAGE = Path(__file__).resolve().parent


def _drop_stale_cache() -> None:
    """Numba's cache (``__pycache__/*.nbi``, ``*.nbc``) is keyed by the file that defines a kernel only: a kernel
    compiled with another module's kernels inside it would be loaded unchanged after that other module changed
    (a ``git checkout``, an edit). So the package's compiled cache is thrown away whenever any of its sources
    changed since it was written, judged by a digest of them all kept beside the cache."""
    digest = hashlib.sha256()
    for src in sorted(_PACKAGE.glob("*.py")):
        digest.update(src.name.encode() + b"\0" + src.read_bytes())
    cache = _PACKAGE / "__pycache__"
    stamp = cache / "slung-compiled.sha256"
    want = digest.hexdigest()
    try:
        if stamp.read_text(encoding="ascii") == want:
            return
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for f in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            f.unlink(missing_ok=True)
        stamp.write_text(want, encoding="ascii")
    except OSError:  # a read-only install: numba caches elsewhere, and an install replaces every file at once
        pass


_drop_stale_cache()

#: the decorator of every kernel (see the module docstring)
kernel = numba.njit(cache=True, error_model="numpy", nogil=True)


def inline_kernel(fn):  # type: ignore[no-untyped-def]
    """A kernel inlined into its callers by numba (small helpers on the hot path)."""
    return numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")(fn)


#: numba's option that leaves out reference counting (numba 0.68; where it is gone, the counts come back)
_NO_NRT = {"_nrt": False} if hasattr(numba.core.cpu.CPUTargetOptions, "_nrt") else {}

#: the decorator of kernels that never create, keep or return an array (the caller owns every array they touch):
#: ``kernel`` without numba's reference counting. Why: numba counts references to the arrays passed into a compiled
#: function, and where the function branches its pruning leaves the counts in place, two to six atomic
#: ``NRT_incref`` / ``NRT_decref`` calls per call of a helper taking arrays; without them the filter's recorded call
#: sequence costs 150 instead of 340 ns per control tick (``tests/test_compiled_kf.py``) and compiles in 18 instead
#: of 32 s. Callable from kernels that count references and from Python alike.
pure_kernel = numba.njit(cache=True, error_model="numpy", nogil=True, **_NO_NRT)


# ---- the estimate (ControlState) ------------------------------------------------------------------------------
EST_FX = 0  # F_x and its derivatives, orders 0..5 (6 floats)
EST_FY = 6  # F_y, orders 0..5
EST_Z = 12
EST_Z_RATE = 13
EST_PHI = 14
EST_THETA = 15
EST_PSI = 16
EST_PHI_RATE = 17
EST_THETA_RATE = 18
EST_PSI_RATE = 19
EST_ALPHA_X = 20
EST_ALPHA_Y = 21
EST_ALPHA_X_RATE = 22
EST_ALPHA_Y_RATE = 23
EST_SIZE = 24

# ---- the reference (FlatSample) -----------------------------------------------------------------------------------
REF_FX = 0  # orders 0..6 (7 floats)
REF_FY = 7
REF_Z = 14
REF_PSI = 21
REF_SIZE = 28

# ---- records and filter events (the codes of estimators.filters.batched_kf / offboard.harness.batched_sensors) ----
POS, ATT, IMU, LOAD = 0, 1, 2, 3
#: an IMU record's gyro, fused with the attitude records
GYRO = 12
#: the first code of a block advance (code - ADVANCE is the block: kin x, y, z, tilt x, y, heading, swing x, y)
ADVANCE = 4
#: fields of a record of each kind after its time
FIELDS = (6, 6, 6, 2)
