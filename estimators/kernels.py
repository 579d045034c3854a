"""What every compiled kernel shares, wherever its role puts it (the filter's in ``estimators/filters/compiled``, the
sweep engine's in ``offboard/harness/compiled``): the JIT decorators, the compile-once cache's digest, the estimate
vector's layout and the filter's record codes, and Python's built-in ``min``, ``max`` and ``math.hypot`` for the
kernels that mirror scalar Python code (``py_min``, ``py_max``, ``py_hypot``: their NaN handling and last bits are
Python's, not numpy's or libm's). In ``estimators/``, the bottom layer, so that every package may import it.

Kernels are numba ``njit`` functions with ``error_model="numpy"`` (a division by zero gives inf or NaN, as numpy
does, instead of raising: the kernels run inside a simulated run, which reports a non-finite state as diverged)
and ``cache=True`` (compiled once per machine, then loaded from ``__pycache__``). No ``fastmath`` but FMA
contraction in the plant's RK4 step (``contracted_kernel``): the kernels keep IEEE arithmetic and the scalar path's
order of operations (but for the plant's FMAs and the plant's and the ``smc`` law's reciprocals and shared sines, a
few ulp), so that a run equals the scalar path's to far below 1e-9 (``tests/test_compiled_engine.py``).

The estimate vector (``EST_SIZE`` floats): ``estimators.model.control_state.ControlState`` flattened, SI units,
world NWU frame as in the scalar path: the flat chains ``F_x``, ``F_y`` (orders 0..5) then the named scalars.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable
from pathlib import Path

import numba
import numpy as np

from estimators import compile_notice  # noqa: F401  (a cold cache's compilation says so, once a process)

#: the project's root (the folder holding ``estimators/``), against which kernel sources are named
ROOT = Path(__file__).resolve().parents[1]


def drop_stale_cache(package: Path, sources: Iterable[Path]) -> bool:
    """Throw away the compiled cache of the kernel package ``package`` (a folder) when any of ``sources`` changed
    since it was written; True when it did (the package's kernels compile on their first call).

    Why: numba's cache (``__pycache__/*.nbi``, ``*.nbc``) is keyed by the file that defines a kernel only: a kernel
    compiled with another module's kernels inside it (inlined or called) would be loaded unchanged after that other
    module changed (a ``git checkout``, an edit). So ``sources`` are the package's own files and every file whose
    kernels or scalar functions its kernels compile in; the judge is a digest of them all, kept beside the cache."""
    digest = hashlib.sha256()
    for src in sources:
        digest.update(src.name.encode() + b"\0" + src.read_bytes())
    cache = package / "__pycache__"
    stamp = cache / "slung-compiled.sha256"
    want = digest.hexdigest()
    try:
        if stamp.read_text(encoding="ascii") == want:
            return False
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for f in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            f.unlink(missing_ok=True)
        stamp.write_text(want, encoding="ascii")
    except OSError:  # a read-only install: numba caches elsewhere, and an install replaces every file at once
        pass
    return True


def kernel_package(init_file: str, shared: Iterable[str], *depends: tuple[Path, ...]) -> tuple[tuple[Path, ...], bool]:
    """A kernel package's sources and whether its cache was stale (and dropped: :func:`drop_stale_cache`), for the
    package's ``__init__`` (``init_file``: its ``__file__``) to call on import, before any of its kernels runs.

    The sources: the package's modules, this module, ``shared`` (paths from the project's root: the scalar modules
    whose functions its kernels compile as they are) and the sources of each kernel package it ``depends`` on
    (their ``SOURCES``), so that a change to a kernel it compiles in drops its cache too."""
    package = Path(init_file).resolve().parent
    own = [*sorted(package.glob("*.py")), Path(__file__).resolve()]  # (every kernel package compiles in this module's)
    files = [*own, *(ROOT / s for s in shared), *(f for d in depends for f in d)]
    sources = tuple(dict.fromkeys(files))
    return sources, drop_stale_cache(package, sources)


#: the decorator of every kernel (see the module docstring)
kernel = numba.njit(cache=True, error_model="numpy", nogil=True)


def inline_kernel(fn):  # type: ignore[no-untyped-def]
    """A kernel inlined into its callers by numba (small helpers on the hot path)."""
    return numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")(fn)


@inline_kernel
def wrap_angle(a: float) -> float:
    """``estimators.model.frames.wrap_angle`` : ``a`` (rad) into (-pi, pi], by
    ``fmod`` (exact; numba has no ``math.fmod``, ``np.fmod`` of floats is C's). ``fmod(w, 2 pi)`` of ``|w| < 2 pi``
    is ``w`` itself, so nearly every call needs no fmod at all; and LLVM, left a plain ``if`` around the call, makes
    it unconditional (it counts a call to a pure function as cheap to speculate), so the call sits behind a loop
    that it does not speculate."""
    two_pi = 2.0 * math.pi
    w = a + math.pi
    while not abs(w) < two_pi:  # (once at most: fmod's result is below 2 pi; NaN and inf: fmod gives NaN)
        w = np.fmod(w, two_pi)
        if w != w:
            break
    if w <= 0.0:
        w = w + two_pi
    return w - math.pi


@inline_kernel
def maximum(a: float, b: float) -> float:
    """``np.maximum(a, b)`` of two floats: NaN if either is; ``b`` when they compare equal (numpy's loop: signed
    zeros). Python's ``max()`` would drop a NaN."""
    if a != a or a > b:
        return a
    return b


@inline_kernel
def minimum(a: float, b: float) -> float:
    """``np.minimum(a, b)`` of two floats: NaN if either is; ``b`` when they compare equal."""
    if a != a or a < b:
        return a
    return b


#: numba's option that leaves out reference counting (numba 0.68; where it is gone, the counts come back)
_NO_NRT = {"_nrt": False} if hasattr(numba.core.cpu.CPUTargetOptions, "_nrt") else {}

#: the decorator of kernels that never create, keep or return an array (the caller owns every array they touch):
#: ``kernel`` without numba's reference counting. Why: numba counts references to the arrays passed into a compiled
#: function, and where the function branches its pruning leaves the counts in place, two to six atomic
#: ``NRT_incref`` / ``NRT_decref`` calls per call of a helper taking arrays; without them the filter's recorded call
#: sequence costs 150 instead of 340 ns per control tick (``tests/test_compiled_kf.py``) and compiles in 18 instead
#: of 32 s. Callable from kernels that count references and from Python alike.
pure_kernel = numba.njit(cache=True, error_model="numpy", nogil=True, **_NO_NRT)

#: ``pure_kernel`` that lets LLVM fuse a multiply and an add into one FMA instruction (``fastmath={"contract"}``,
#: the one fast-math flag that only removes a rounding: no reordering, no approximation, NaN and inf kept). For
#: the plant's RK4 only, where it takes 20 % off the step (106 -> 86 ns on this machine, 6 Dec 2026) and its
#: tests compare with the scalar plant to a few ulp anyway; not for the kernels tested bit for bit against the
#: scalar path (the filter, the laws, PX4's loops), whose last bits an FMA would change.
contracted_kernel = numba.njit(cache=True, error_model="numpy", nogil=True, fastmath={"contract"}, **_NO_NRT)


def pack_constants(size: int, values: dict[int, float]) -> np.ndarray:
    """A kernel's constants vector of ``size`` floats from ``{index: value}``; every index given once (a layout whose
    named indices overlap or leave a gap fails here, not as a wrong constant inside a run)."""
    if sorted(values) != list(range(size)):
        raise AssertionError(f"constants layout: indices {sorted(values)} are not 0..{size - 1}")
    c = np.empty(size)
    for i, v in values.items():
        c[i] = float(v)
    return c


@inline_kernel
def py_min(a: float, b: float) -> float:
    """Python's built-in ``min(a, b)`` of two floats: ``b`` only when ``b < a`` (so a NaN ``a`` is kept, a NaN ``b``
    is not taken), as the scalar path's ``min`` gives it."""
    return b if b < a else a


@inline_kernel
def py_max(a: float, b: float) -> float:
    """Python's built-in ``max(a, b)`` of two floats: ``b`` only when ``b > a``."""
    return b if b > a else a


#: Veltkamp's constant 2^27 + 1: splits a double into two halves whose products are exact
_T27 = 134217729.0


@inline_kernel
def _split(x: float) -> tuple[float, float]:
    """``x`` as ``hi + lo`` with 26-bit halves (Veltkamp-Dekker)."""
    t = x * _T27
    hi = t - (t - x)
    return hi, x - hi


@inline_kernel
def _fast_sum(csum: float, x: float) -> tuple[float, float]:
    """``csum + x`` and its rounding error (Neumaier, ``|csum| >= |x|``)."""
    total = csum + x
    return total, (csum - total) + x


@pure_kernel
def py_hypot(a: float, b: float) -> float:
    """CPython 3.11's ``math.hypot(a, b)`` (``Modules/mathmodule.c``, ``vector_norm``): the sum of squares of the
    scaled coordinates in double-double arithmetic (exact squares by Veltkamp-Dekker splitting, compensated sums), its
    square root with one differential correction. numba's ``math.hypot`` is libm's, which differs from it in the last
    bit for about one argument pair in a thousand (``tests/test_compiled_attitude.py``)."""
    a, b = abs(a), abs(b)
    m = b if b > a else a
    if math.isinf(m):
        return m
    if a != a or b != b:
        return math.nan
    if m == 0.0:
        return m
    _, max_e = math.frexp(m)
    if max_e < -1023:  # subnormal: the scale 2^-max_e would overflow; divided by the largest instead
        csum, e1 = _fast_sum(1.0, (a / m) * (a / m))
        csum, e2 = _fast_sum(csum, (b / m) * (b / m))
        return m * math.sqrt(csum - 1.0 + (0.0 + e1 + e2))
    scale = math.ldexp(1.0, -max_e)
    csum, frac1, frac2, frac3 = 1.0, 0.0, 0.0, 0.0
    for v in (a, b):
        hi, lo = _split(v * scale)  # lossless scaling into [0.5, 1), then exact squares
        csum, e = _fast_sum(csum, hi * hi)
        frac1 += e
        csum, e = _fast_sum(csum, 2.0 * hi * lo)
        frac2 += e
        frac3 += lo * lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
    hi, lo = _split(h)  # the differential correction: h^2 taken from the sum exactly
    csum, e = _fast_sum(csum, -hi * hi)
    frac1 += e
    csum, e = _fast_sum(csum, -2.0 * hi * lo)
    frac2 += e
    csum, e = _fast_sum(csum, -lo * lo)
    frac3 += e
    x = csum - 1.0 + (frac1 + frac2 + frac3)
    return (h + x / (2.0 * h)) / scale


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

# ---- records and filter events (the codes of the compiled schedule and filter) -------------------------------------
POS, ATT, IMU, LOAD = 0, 1, 2, 3
#: an IMU record's gyro, fused with the attitude records
GYRO = 12
#: the first code of a block advance (code - ADVANCE is the block: kin x, y, z, tilt x, y, heading, swing x, y)
ADVANCE = 4
#: fields of a record of each kind after its time
FIELDS = (6, 6, 6, 2)
