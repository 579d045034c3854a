"""The attitude-level law's horizontal disturbance observer (no load): what accelerates the vehicle besides its tilt.

The attitude-level law (``offboard.control.smc_attitude``) takes the vehicle's horizontal acceleration as the tilt's,
``g n / n3``. On real PX4 something else accelerates it too: the estimate's attitude is off the true one by a degree
or two (a tilt the law does not know of), drag, wind. Through the law's integral alone such an acceleration is
rejected slowly (0.56 m of error per m/s^2 at 0.1 Hz for the SIH quadrotor's gains); estimated from the velocity it
enters the law's acceleration error directly (docs/model.md section 12.2). A pure step: the state lives in
:class:`offboard.control.smc.ControllerMemory` (``dist_x``, ``dist_y``, ``vel_x``, ``vel_y``).
"""

from __future__ import annotations

import math

from offboard.control.smc import ControllerMemory

#: longest step (s) the disturbance observer integrates at once (a stalled loop must not make it jump)
DIST_STEP_MAX = 0.05


def observe_disturbance(
    memory: ControllerMemory,
    dt: float,
    vx: float,
    vy: float,
    acc_x: float,
    acc_y: float,
    wn_d: float,
    dist_max: float,
) -> tuple[float, float, float, float]:
    """One step of the horizontal disturbance observer (docs/model.md section 12.2), per world axis
    ``v' = a_tilt + d``, ``d`` constant: ``v_hat' = a_tilt + d_hat + 2 wn_d (v - v_hat)``,
    ``d_hat' = wn_d^2 (v - v_hat)`` (error poles at ``-wn_d``, double). vx, vy: the estimated velocity (m/s);
    acc_x, acc_y: the tilt's acceleration ``g n / n3`` (m/s^2). The estimate is bounded by what the tilt limit can
    oppose, ``g tan(tilt_max)`` (a disturbance beyond it cannot be rejected; bad velocity data must not wind it up).
    Returns (d_x, d_y, v_hat_x, v_hat_y)."""
    if wn_d <= 0.0:
        return 0.0, 0.0, memory.vel_x, memory.vel_y
    if not (math.isfinite(memory.vel_x) and math.isfinite(memory.vel_y)):  # the first step: start at rest
        return 0.0, 0.0, vx, vy
    h = min(dt, DIST_STEP_MAX)
    ev_x, ev_y = vx - memory.vel_x, vy - memory.vel_y
    w2 = wn_d * wn_d
    d_x = memory.dist_x + h * w2 * ev_x
    d_y = memory.dist_y + h * w2 * ev_y
    norm = math.hypot(d_x, d_y)
    if norm > dist_max:
        d_x, d_y = d_x * dist_max / norm, d_y * dist_max / norm
    vel_x = memory.vel_x + h * (acc_x + d_x + 2.0 * wn_d * ev_x)
    vel_y = memory.vel_y + h * (acc_y + d_y + 2.0 * wn_d * ev_y)
    return d_x, d_y, vel_x, vel_y


__all__ = ["DIST_STEP_MAX", "observe_disturbance"]
