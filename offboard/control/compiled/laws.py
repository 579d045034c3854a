"""The controllers of a compiled run, one run at a time: the driver's one entry to them. :func:`law_step` dispatches
one tick to the sliding-mode law ``offboard.control.smc.step`` (the ``smc`` row, :mod:`.smc_law`) or to a baseline
(:mod:`.baseline_laws`: the stock cascade ``cascade``, and ``zv`` / ``zvd`` behind a reference shaped beforehand by
the driver; the swing-feedback cascade ``swing-feedback``; LQR with its motor-lag states ``lqr``), in the order of
the scalar laws' expressions (``offboard.control.smc``, ``offboard.control.controllers``).

A law is a code (``LAW_*``), a float64 constants vector ``c`` (its indices named by the ``S_*`` (smc), ``C_*``
(cascade, swing-feedback) and ``Q_*`` (LQR) constants), the LQR gain ``K`` (empty for the others), all from
:func:`law_constants`, and a run's memory (:func:`law_memory`, indices ``M_*`` / ``B_*``): :func:`law_step` is
one control tick of one run. Frames and units as in the scalar path: model frame (world NWU, z up; body FLU), SI,
rad; the estimate and the reference are the vectors of ``estimators.kernels`` and :mod:`.reference_row`.

As the scalar laws: the baselines screen the estimate (a run whose estimate is not finite gets the nominal hover
command and keeps its memory; each baseline's ``dt`` from its own last step time); ``smc`` does not screen (its
``dt`` is the caller's; a NaN flows through its arithmetic, and into its memory). Numpy's
``maximum`` / ``minimum`` (NaN propagates; between equal values the second argument) and ``clip`` (a value equal
to a bound, or NaN, passes unchanged) are mirrored by ``kernels.maximum``, ``kernels.minimum`` and
``smc_law._clip``.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.kernels import EST_FX, EST_FY, EST_SIZE, EST_Z, inline_kernel, maximum, pure_kernel
from estimators.model.vehicle import Vehicle
from offboard.control import smc
from offboard.control.compiled.baseline_laws import (
    B_DELIVERED,
    B_T_LAST,
    B_VEL_X,
    B_VEL_Y,
    BASE_HOVER,
    CASCADE_MEMORY,
    CASCADE_SIZE,
    LQR_MEMORY,
    LQR_SIZE,
    SWING_MEMORY,
    SWING_SIZE,
    _cascade_constants,
    _lqr_constants,
    cascade_step,
    lqr_step,
    swing_offsets,
)
from offboard.control.compiled.smc_law import (
    M_LAG_DT,
    SMC_MEMORY,
    SMC_SIZE,
    _smc_constants,
    smc_step,
)

LAW_SMC, LAW_CASCADE, LAW_SWING_FEEDBACK, LAW_LQR = 0, 1, 2, 3
#: the sweep's rows these laws fly (the registry's controllers of these names; ``zv`` / ``zvd``: the cascade behind
#: the reference shaper)
TORQUE_LAWS = ("smc", "cascade", "zv", "zvd", "swing-feedback", "lqr")

_SIZES = {LAW_SMC: SMC_SIZE, LAW_CASCADE: CASCADE_SIZE, LAW_SWING_FEEDBACK: SWING_SIZE, LAW_LQR: LQR_SIZE}


# ---- Python side: the constants and the initial memory ------------------------------------------------------------
def law_constants(law: str, vehicle: Vehicle, params: smc.ControllerParams) -> tuple[int, np.ndarray, np.ndarray]:
    """(code, constants ``c``, LQR gain ``K``: 4 x 20 or 4 x 24, empty (0, 0) for the other laws) of a row of
    :data:`TORQUE_LAWS` flown by the nominal ``vehicle``; ``params``: ``smc``'s law (``registry.smc_params(nominal)``,
    as the sweep passes it). The baselines' figures come from the registry's own controllers (gains, the applet's
    constants, LQR's gain), so the paths cannot drift apart; ``zv`` / ``zvd`` are the cascade (their shaped
    reference is the driver's)."""
    from offboard.control.controllers import registry
    from offboard.control.controllers.lqr import LqrController
    from offboard.control.controllers.shaping import ShapedCascade

    if law not in TORQUE_LAWS:
        raise ValueError(f"the compiled laws are {', '.join(TORQUE_LAWS)}, not {law!r}")
    no_gain = np.zeros((0, 0))
    if law == "smc":
        return LAW_SMC, _smc_constants(params), no_gain
    scalar = registry.make(law, vehicle)
    if isinstance(scalar, LqrController):
        return LAW_LQR, _lqr_constants(scalar), np.array(scalar.K, dtype=np.float64)
    if isinstance(scalar, ShapedCascade):
        scalar = scalar.cascade
    from offboard.control.controllers.swing_feedback import SwingFeedbackCascade

    code = LAW_SWING_FEEDBACK if isinstance(scalar, SwingFeedbackCascade) else LAW_CASCADE
    return code, _cascade_constants(scalar, vehicle), no_gain


def law_memory(code: int, c: np.ndarray) -> np.ndarray:
    """A run's memory before its first tick for the law ``code`` with constants ``c`` (checked against the code):
    smc's 8 zeros (and its lag factor's cache, empty); the baselines' integrators at zero, their last step time
    NaN (and LQR's delivered thrust and torques NaN: set to the feed-forward at the first step)."""
    if code not in _SIZES or c.shape != (_SIZES[code],):
        raise ValueError(f"law code {code} with {c.shape} constants: not a pair law_constants gives")
    if code == LAW_SMC:
        mem = np.zeros(SMC_MEMORY)
        mem[M_LAG_DT] = math.nan
        return mem
    size = {LAW_CASCADE: CASCADE_MEMORY, LAW_SWING_FEEDBACK: SWING_MEMORY, LAW_LQR: LQR_MEMORY}[code]
    mem = np.zeros(size)
    mem[B_T_LAST] = math.nan
    if code == LAW_LQR:
        mem[B_DELIVERED : B_DELIVERED + 4] = math.nan
    return mem


# ---- the baselines' screen -------------------------------------------------------------------------------------------
@inline_kernel
def estimate_is_finite(est: np.ndarray) -> bool:
    """The baselines' screen (``BatchedBaseline``) and the attitude-level law's (``ControlState.is_finite``): the sum
    of the two flat chains and the named scalars, summed as numpy and Python sum them (an overflowing sum is refused
    too), is finite."""
    sx = est[EST_FX]
    sy = est[EST_FY]
    for i in range(1, 6):
        sx = sx + est[EST_FX + i]
        sy = sy + est[EST_FY + i]
    rest = 0.0
    for i in range(EST_Z, EST_SIZE):
        rest = rest + est[i]
    return math.isfinite(sx + sy + rest)


# ---- one tick --------------------------------------------------------------------------------------------------------
@pure_kernel
def law_step(
    code: int,
    c: np.ndarray,
    K: np.ndarray,
    mem: np.ndarray,
    t: float,
    dt: float,
    est: np.ndarray,
    ref: np.ndarray,
    u_out: np.ndarray,
) -> bool:
    """One control tick of one run: ``t`` (s); ``dt`` (s) since the previous tick (0 at the first; ``smc``'s,
    the baselines use their own last step time); ``est`` the estimate (``EST_*``), ``ref`` the reference row
    (``REF_*``); the command (thrust N, tau_phi, tau_theta, tau_psi N m, body FLU) into ``u_out`` (4,), ``mem``
    updated in place. Returns ``saturated``."""
    if code == LAW_SMC:
        return smc_step(c, mem, dt, est, ref, u_out)
    if not estimate_is_finite(est):  # the baselines: hover, memory kept
        u_out[0], u_out[1], u_out[2], u_out[3] = c[BASE_HOVER], 0.0, 0.0, 0.0
        return False
    t_last = mem[B_T_LAST]
    own_dt = 0.0 if math.isnan(t_last) else maximum(0.0, t - t_last)
    mem[B_T_LAST] = t
    if code == LAW_LQR:
        return lqr_step(c, K, mem, own_dt, est, ref, u_out)
    if code == LAW_SWING_FEEDBACK:
        offs = swing_offsets(c, mem, own_dt, est)
    elif code == LAW_CASCADE:
        offs = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    else:
        raise ValueError("unknown law code")
    return cascade_step(c, mem, own_dt, est, ref, offs, u_out)


__all__ = [
    "B_VEL_X",
    "B_VEL_Y",
    "LAW_CASCADE",
    "LAW_LQR",
    "LAW_SMC",
    "LAW_SWING_FEEDBACK",
    "TORQUE_LAWS",
    "estimate_is_finite",
    "law_constants",
    "law_memory",
    "law_step",
]
