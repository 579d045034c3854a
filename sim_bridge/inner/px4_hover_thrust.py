"""PX4's hover thrust estimator (``mc_hover_thrust_estimator``), as the emulator's PX4 flavour runs it.

Real PX4 does not fly its position-controlled modes on MPC_THR_HOVER alone: a one-state Kalman filter learns the
normalized thrust that holds a hover from the measured vertical acceleration and the position controller's vertical
thrust, and once that estimate is trusted the position controller flies with it (MPC_USE_HTE, on by default),
moving its velocity integrator so that the thrust does not jump. A vehicle whose MPC_THR_HOVER is wrong (a payload
added, a vehicle file written for another autopilot) therefore overshoots its first climb and then holds height
as if the parameter were right. Without this model the emulator kept the wrong belief for the whole flight.

The filter (PX4's ``ZeroOrderHoverThrustEkf``, modelled from its documented equations, not copied): the state
``h`` (hover thrust, 0..1) is constant with process noise ``HTE_HT_NOISE`` (per s); the measurement is the vertical
acceleration ``a = g T / h - g`` (up, m/s^2) for the vertical thrust ``T`` (normalized, up); innovations beyond
``HTE_ACC_GATE`` standard deviations are refused, and a run of refusals (a low-passed signed test ratio above 0.2)
inflates the state variance so the filter can follow a sudden change; the acceleration noise is learned from the
residuals (2 s time constant, 1..400 (m/s^2)^2), scaled up above ``HTE_VZ_THR`` / ``HTE_VXY_THR`` of speed; ``h``
is kept within ``MPC_THR_HOVER +- HTE_THR_RANGE``. The estimate is valid once its variance is below 0.001 and
its test ratio below 1, continuously for 2 s. It runs while armed, in the air (above 1 m once since the last
landing) and under PX4's position controller; disarming resets it to MPC_THR_HOVER.
"""

from __future__ import annotations

import math

#: PX4's defaults of the HTE_* parameters (``hover_thrust_estimator_params.yaml``)
HTE_DEFAULTS = {
    "HTE_HT_NOISE": 0.0036,
    "HTE_ACC_GATE": 3.0,
    "HTE_HT_ERR_INIT": 0.1,
    "HTE_VXY_THR": 10.0,
    "HTE_VZ_THR": 2.0,
    "HTE_THR_RANGE": 0.2,
}
#: time constants (s) of the residual's low-pass and of the noise learning; the validity hysteresis (s)
RESIDUAL_LPF_S = 1.0
NOISE_LEARNING_S = 2.0
VALID_AFTER_S = 2.0
#: the estimate is trusted below this variance (normalized thrust^2)
VALID_VARIANCE = 0.001
#: height (m) above which the vehicle counts as in the air (PX4: distance to the ground above 1 m)
IN_AIR_HEIGHT_M = 1.0


class HoverThrustEstimator:
    """The hover thrust estimate of one PX4 vehicle; ``gravity`` in m/s^2, thrusts normalized 0..1."""

    def __init__(self, gravity: float, hover_param: float, params: dict[str, float] | None = None) -> None:
        self.g = gravity
        self.p = dict(HTE_DEFAULTS if params is None else params)
        self.reset(hover_param)

    def reset(self, hover_param: float) -> None:
        """Back to MPC_THR_HOVER (``hover_param``) with the initial uncertainty (PX4 does this while disarmed)."""
        self.hover_param = hover_param
        rng = self.p["HTE_THR_RANGE"]
        self.h_min = min(max(hover_param - rng, 0.0), 0.8)
        self.h_max = min(max(hover_param + rng, 0.2), 0.9)
        self.h = min(max(hover_param, 0.1), 0.9)
        self.var = self.p["HTE_HT_ERR_INIT"] ** 2
        self.acc_var = 5.0
        self.residual_lpf = 0.0
        self.ratio_lpf = 0.0
        self.test_ratio = 0.0
        self.valid = False
        self._valid_for = 0.0
        self.in_air = False

    def update(self, dt: float, acc_up: float, thrust_up: float, speed_xy: float, speed_z: float) -> None:
        """One fusion: ``dt`` s since the last, the measured vertical acceleration ``acc_up`` (m/s^2, up), the
        position controller's vertical thrust ``thrust_up`` (normalized, up), the horizontal and vertical speeds
        (m/s) that scale the noise."""
        if not (dt > 0.001 and dt < 1.0 and math.isfinite(acc_up) and math.isfinite(thrust_up)):
            return
        g = self.g
        self.var += self.p["HTE_HT_NOISE"] ** 2 * dt * dt
        scale = max(abs(speed_z) - self.p["HTE_VZ_THR"] + 1.0, speed_xy - self.p["HTE_VXY_THR"] + 1.0, 1.0)
        acc_var = self.acc_var * scale * scale
        H = -g * thrust_up / (self.h * self.h)
        innov_var = max(H * self.var * H + acc_var, acc_var)
        innov = acc_up - (g * thrust_up / self.h - g)
        gate = self.p["HTE_ACC_GATE"]
        self.test_ratio = innov * innov / (gate * gate * innov_var)
        residual = innov
        if self.test_ratio < 1.0:
            k = self.var * H / innov_var
            self.h = min(max(self.h + k * innov, self.h_min), self.h_max)
            self.var = min(max((1.0 - k * H) * self.var, 1e-10), 1.0)
            residual = acc_up - (g * thrust_up / self.h - g)
        elif abs(self.ratio_lpf) > 0.2:  # refused for a while: the hover thrust moved, let the filter follow
            self.var += 1e3 * self.p["HTE_HT_NOISE"] ** 2 * dt
        a = dt / (RESIDUAL_LPF_S + dt)
        self.residual_lpf = (1.0 - a) * self.residual_lpf + a * residual
        signed = math.copysign(min(self.test_ratio, 1.0), innov)
        self.ratio_lpf = (1.0 - a) * self.ratio_lpf + a * signed
        b = dt / (NOISE_LEARNING_S + dt)
        r = residual - self.residual_lpf
        self.acc_var = min(max((1.0 - b) * self.acc_var + b * (r * r + H * self.var * H), 1.0), 400.0)
        ok = self.var < VALID_VARIANCE and (self.valid or self.test_ratio < 1.0)
        self._valid_for = self._valid_for + dt if ok else 0.0
        self.valid = self._valid_for >= VALID_AFTER_S if not self.valid else ok


def integrator_after_hover_change(int_z: float, acc_up: float, gravity: float, old: float, new: float) -> float:
    """PX4's position controller on a new hover thrust: the vertical velocity integrator moved so that the thrust
    ``(g + a) h / g`` does not jump, ``a`` the current vertical acceleration setpoint (m/s^2, up) of which the
    integrator is a part."""
    a_new = (gravity + acc_up) * old / new - gravity
    return int_z + a_new - acc_up


__all__ = ["HTE_DEFAULTS", "HoverThrustEstimator", "integrator_after_hover_change"]
